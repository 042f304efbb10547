"""``groundstation router`` with mutual TLS and access control by certificate common name.

Separate processes in separate working directories on loopback, free ports: the router
(``groundstation router --config``), a real daemon (``groundstation run`` on the simulator's
TCP stream) publishing through TLS with the ``rover`` certificate, small client processes that
open the project's bus with one certificate each and put on a few keys, and an observer (this
process) on the router's plain-TCP loopback endpoint that records what arrives. Certificates are
made by running the recipe of ``docs/security.md`` verbatim (X.509 v3, ``openssl``), twice: two
unrelated CAs.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest
from peers import REPO, CliProc, cli_env, free_port, wait_until

from groundstation.bus import Bus, open_bus
from groundstation.config import ZenohSettings

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl CLI")

WAIT_S = 60.0

T = TypeVar("T")


def recipe() -> str:
    """The certificate recipe block of docs/security.md."""
    doc = (REPO / "docs" / "security.md").read_text()
    found = re.search(r"<!-- recipe:certs[^\n]*-->\n```sh\n(.*?)```", doc, re.S)
    assert found, "docs/security.md lost its recipe block"
    return found.group(1)


def make_ca(where: Path) -> Path:
    where.mkdir()
    subprocess.run(["bash", "-c", recipe()], cwd=where, check=True, capture_output=True)
    return where


def tls_router(cwd: Path, ca: Path, listen: str) -> CliProc:
    """``groundstation router`` in ``cwd``, set by the environment alone: listening on
    ``listen``, mutual TLS with the certificates of ``ca`` (:func:`make_ca`), access control
    on with ``solver`` the solvers' common name."""
    return CliProc(cwd, "router", env={
        "GROUNDSTATION_ROUTER_LISTEN": listen,
        "GROUNDSTATION_ROUTER_TLS_CA": str(ca / "ca.pem"),
        "GROUNDSTATION_ROUTER_TLS_CERTIFICATE": str(ca / "router.pem"),
        "GROUNDSTATION_ROUTER_TLS_PRIVATE_KEY": str(ca / "router.key"),
        "GROUNDSTATION_ROUTER_ACCESS_ENABLED": "true",
        "GROUNDSTATION_ROUTER_ACCESS_SOLVERS": "solver",
    })


def when_up(router: CliProc, connect: Callable[[], T]) -> T:
    """``connect()``'s result once it succeeds (the router takes a while to listen); fails with
    the router's stderr if the router exits meanwhile."""
    def attempt() -> T | None:
        assert router.proc.poll() is None, router.stderr()
        try:
            return connect()
        except Exception:  # not listening yet: the next attempt may succeed
            return None

    got = wait_until(attempt, WAIT_S, "the router up", poll_s=0.2)
    assert got is not None
    return got


class Observer:
    """Subscribes to everything through the router's loopback TCP endpoint."""

    def __init__(self, endpoint: str) -> None:
        self.got: list[tuple[str, bytes]] = []
        self._lock = threading.Lock()
        self.bus: Bus = open_bus(ZenohSettings(mode="client", listen=(), connect=(endpoint,)))
        self.bus.subscribe("groundstation/**", self._on)

    def _on(self, key: str, payload: bytes) -> None:
        with self._lock:
            self.got.append((key, payload))

    def keys_from(self, tag: bytes) -> set[str]:
        with self._lock:
            return {k for k, p in self.got if p == tag}

    def seen(self) -> set[str]:
        with self._lock:
            return {k for k, _ in self.got}


CLIENT = """
import sys, time
from pathlib import Path
from groundstation.bus import open_bus
from groundstation.config import ZenohSettings
from groundstation.errors import GroundstationError
endpoint, ca, cert, key, tag, *keys = sys.argv[1:]
try:
    bus = open_bus(ZenohSettings(mode="client", listen=(), connect=(endpoint,), tls_ca=Path(ca),
                                 tls_certificate=Path(cert) if cert else None,
                                 tls_private_key=Path(key) if key else None))
except GroundstationError as err:
    print("refused:", err)
    sys.exit(3)
time.sleep(1.0)  # the router's interest reaches this client before it puts
for _ in range(3):
    for k in keys:
        bus.put(k, tag.encode())
    time.sleep(0.3)
bus.close()
print("published")
"""


def client(tmp: Path, endpoint: str, ca: Path, cert: Path | None, tag: str,
           *keys: str) -> subprocess.CompletedProcess[str]:
    cwd = tmp / f"client-{tag}"
    cwd.mkdir()
    key = cert.with_suffix(".key") if cert else None
    return subprocess.run(
        [sys.executable, "-c", CLIENT, endpoint, str(ca), str(cert or ""), str(key or ""), tag,
         *keys], cwd=cwd, env=cli_env(), capture_output=True, text=True, timeout=60)


def wait(check: Callable[[], object]) -> None:
    """:func:`wait_until` with this module's generous timeout."""
    wait_until(check, WAIT_S, "the condition", poll_s=0.2)


def test_recipe_makes_x509_v3_certificates(tmp_path: Path) -> None:
    ca = make_ca(tmp_path / "ca")
    for name in ("ca", "router", "rover", "base", "solver"):
        text = subprocess.run(["openssl", "x509", "-in", str(ca / f"{name}.pem"), "-noout",
                               "-text"], check=True, capture_output=True, text=True).stdout
        assert "Version: 3 (0x2)" in text, name
        assert "X509v3 Basic Constraints" in text, name


@pytest.mark.slow
def test_mtls_router_admits_by_certificate_and_confines_each_station(tmp_path: Path) -> None:
    ca, other = make_ca(tmp_path / "ca1"), make_ca(tmp_path / "ca2")
    tls_port, tcp_port = free_port(), free_port()
    tls, local = f"tls/localhost:{tls_port}", f"tcp/127.0.0.1:{tcp_port}"
    rdir = tmp_path / "router"
    rdir.mkdir()
    (rdir / "router.toml").write_text(f"""
listen = ["tls/127.0.0.1:{tls_port}", "{local}"]
[tls]
ca = "{ca / 'ca.pem'}"
certificate = "{ca / 'router.pem'}"
private_key = "{ca / 'router.key'}"
mtls = true
[access]
enabled = true
local = true
solvers = ["solver"]
[stations.rover]
cert_common_names = ["rover"]
[stations.base]
""")
    procs: list[CliProc] = []
    try:
        router = CliProc(rdir, "router", "--config", "router.toml")
        procs.append(router)
        obs = when_up(router, lambda: Observer(local))
        time.sleep(0.5)

        # a real daemon with the rover certificate publishes its status through TLS
        sim_port = free_port()
        ddir = tmp_path / "rover"
        ddir.mkdir()
        procs.append(CliProc(tmp_path / "sim", "simulate", "--tcp", str(sim_port),
                             "--duration", "600", "--speed", "1"))
        (ddir / "rover.toml").write_text(f"""
station = "rover"
[source]
address = "127.0.0.1:{sim_port}"
[zenoh]
mode = "client"
listen = []
connect = ["{tls}"]
tls_ca = "{ca / 'ca.pem'}"
tls_certificate = "{ca / 'rover.pem'}"
tls_private_key = "{ca / 'rover.key'}"
""")
        procs.append(CliProc(ddir, "run", "--config", "rover.toml"))
        wait(lambda: "groundstation/rover/status" in obs.seen())

        # the same CN from another CA: refused at the handshake, nothing arrives
        out = client(tmp_path, tls, ca / "ca.pem", other / "rover.pem", "foreign",
                     "groundstation/rover/status")
        assert out.returncode == 3 and "refused: cannot open Zenoh session" in out.stdout, out
        assert "Traceback" not in out.stderr
        # no certificate at all: refused too (mutual TLS)
        out = client(tmp_path, tls, ca / "ca.pem", None, "anonymous",
                     "groundstation/rover/status")
        assert out.returncode == 3, out

        # same CA, station "base": its own keys pass, the rover's and others are denied
        out = client(tmp_path, tls, ca / "ca.pem", ca / "base.pem", "base",
                     "groundstation/base/status", "groundstation/rover/status",
                     "groundstation/rover/timemark", "elsewhere/x")
        assert out.returncode == 0, out
        wait(lambda: obs.keys_from(b"base") == {"groundstation/base/status"})

        # the rover certificate from a second process: its keys pass, base's do not
        out = client(tmp_path, tls, ca / "ca.pem", ca / "rover.pem", "rover2",
                     "groundstation/rover/timemark", "groundstation/base/status")
        assert out.returncode == 0, out
        wait(lambda: obs.keys_from(b"rover2") == {"groundstation/rover/timemark"})

        # a solver writes the solution only
        out = client(tmp_path, tls, ca / "ca.pem", ca / "solver.pem", "solver",
                     "groundstation/rover/solution", "groundstation/rover/status")
        assert out.returncode == 0, out
        wait(lambda: obs.keys_from(b"solver") == {"groundstation/rover/solution"})

        time.sleep(1.0)  # late arrivals of denied keys would show now
        assert obs.keys_from(b"foreign") == set() and obs.keys_from(b"anonymous") == set()
        assert obs.keys_from(b"base") == {"groundstation/base/status"}
        assert obs.keys_from(b"rover2") == {"groundstation/rover/timemark"}
        assert obs.keys_from(b"solver") == {"groundstation/rover/solution"}
        obs.bus.close()
    finally:
        for p in procs:
            p.stop()


def test_solver_certificate_reads_every_station(tmp_path: Path) -> None:
    ca = make_ca(tmp_path / "ca")
    tls_port, tcp_port = free_port(), free_port()
    router = tls_router(tmp_path / "router", ca,
                        f"tls/127.0.0.1:{tls_port},tcp/127.0.0.1:{tcp_port}")
    solver: Bus | None = None
    local: Bus | None = None
    try:
        got: list[str] = []
        solver = when_up(router, lambda: open_bus(ZenohSettings(
            mode="client", listen=(), connect=(f"tls/localhost:{tls_port}",),
            tls_ca=ca / "ca.pem", tls_certificate=ca / "solver.pem",
            tls_private_key=ca / "solver.key")))
        solver.subscribe("groundstation/**", lambda k, p: got.append(k))
        local = open_bus(ZenohSettings(mode="client", listen=(),
                                       connect=(f"tcp/127.0.0.1:{tcp_port}",)))
        local.queryable("groundstation/base/q/status", lambda: [b"{}"])

        def delivered() -> bool:
            assert local is not None
            local.put("groundstation/base/status", b"{}")
            local.put("groundstation/rover/timemark", b"{}")
            return {"groundstation/base/status", "groundstation/rover/timemark"} <= set(got)

        wait(delivered)
        assert solver.get("groundstation/base/q/status") == [("groundstation/base/q/status",
                                                               b"{}")]
    finally:
        for b in (solver, local):
            if b is not None:
                b.close()
        router.stop()


def test_router_bad_configuration_exits_2_naming_the_key(tmp_path: Path) -> None:
    cases = [
        ({"GROUNDSTATION_ROUTER_LISTEN": "tls/127.0.0.1:7448"}, "tls.certificate"),
        ({"GROUNDSTATION_ROUTER_TLS_CA": str(tmp_path / "missing.pem")}, "tls.ca"),
        ({"GROUNDSTATION_ROUTER_ACCESS_ENABLED": "maybe"}, "access.enabled"),
        ({"GROUNDSTATION_ROUTER_LISTNE": "x"}, "GROUNDSTATION_ROUTER_LISTNE"),
    ]
    for extra, name in cases:
        out = subprocess.run([sys.executable, "-m", "groundstation.cli", "router"],
                             cwd=tmp_path, env=cli_env(**extra), capture_output=True, text=True,
                             timeout=60)
        assert out.returncode == 2, (extra, out.stderr)
        assert name in out.stderr and "Traceback" not in out.stderr, out.stderr
