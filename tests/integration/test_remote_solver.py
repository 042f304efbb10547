"""A remote solver fetches a station's recording through the router, byte for byte, and
solves it (issue 16: recordings over Zenoh). Also: each rotated part served while the daemon
records, serving after the session until told to stop, and the same over mutual TLS with
access control (another station's certificate is not answered).

Separate processes in separate working directories, real Zenoh on loopback, free ports:

- ``groundstation router`` (access control on, loopback TCP allowed) in ``router/``;
- ``groundstation demo --station rover`` in ``A/``: its daemon finds the router's endpoint
  taken and joins it; after the flight it keeps serving its recording (``--serve-after``);
- ``groundstation solver`` in ``B/``, connected to the router, its recording roots and output
  inside ``B/`` only: the path the session message names is not readable there, so it fetches
  the file over the bus into ``B/solutions/rover/``, checks it, solves it and publishes;
- this process, a client of the router: subscribes to the solutions, and asks
  ``q/solution`` afterwards, as a late joiner would.
"""

from __future__ import annotations

import json
import shutil
import signal
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest
from peers import CliProc, Received, free_port, wait_until

from groundstation import messages
from groundstation.bus import Bus, decode, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.storage import reading
from groundstation.storage.transfer import sha256_file

WAIT_S = 120.0  # generous: the shared 2-core machine

T = TypeVar("T")


class Running:
    """A test's processes and bus sessions, ended together when the test ends."""

    def __init__(self) -> None:
        self.procs: list[CliProc] = []
        self.buses: list[Bus] = []

    def start(self, cwd: Path, *argv: str) -> CliProc:
        """``groundstation *argv`` in ``cwd``, waiting for its lines as long as this module's
        processes need."""
        self.procs.append(CliProc(cwd, *argv, wait_s=WAIT_S))
        return self.procs[-1]

    def keep(self, bus: Bus) -> Bus:
        self.buses.append(bus)
        return bus

    def close(self) -> None:
        """The buses closed, then the processes stopped, the last started first."""
        for bus in self.buses:
            bus.close()
        for p in reversed(self.procs):
            p.stop()


@pytest.fixture
def running() -> Iterator[Running]:
    r = Running()
    try:
        yield r
    finally:
        r.close()


def _final(sols: Received) -> dict[str, Any] | None:
    """The last solution message that is a verdict (not "solving"), if any yet."""
    done = sols.all(lambda m: m.get("status") not in ("solving", None))
    return done[-1] if done else None


def _until(check: Callable[[], T | None], what: str, timeout_s: float = WAIT_S) -> T:
    """:func:`wait_until` with this module's generous timeout: ``check()``'s value once true."""
    got = wait_until(check, timeout_s, what, poll_s=0.2)
    assert got is not None
    return got


def _rover_on_simulator(running: Running, tmp_path: Path, top: str = "", more: str = "",
                        zenoh: str = "") -> tuple[CliProc, Bus, Received]:
    """The simulator streaming on TCP (in ``sim/``) and ``groundstation run`` recording it in
    ``A/`` (its ``rover.toml``: top-level keys ``top``, tables ``more``, ``[zenoh]`` keys
    ``zenoh``) and listening on a free endpoint; this process a client of it, keeping the
    rover's session messages. Returns the daemon, the bus and the messages."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    sim_port = free_port()
    sim = running.start(tmp_path / "sim", "simulate", "--tcp", str(sim_port), "--duration",
                        "600", "--speed", "1")
    # the daemon only once the simulator listens: started before it on a loaded machine, the
    # daemon of a 4 s session found nothing to connect to for all of it and exited 1 ("no
    # data received"; a fresh clone's suite run)
    wait_until(lambda: "listening on tcp" in sim.out_path.read_text(), 60,
               "the simulator listening")
    a_dir = tmp_path / "A"
    a_dir.mkdir()
    (a_dir / "rover.toml").write_text(
        f'station = "rover"\n{top}[source]\naddress = "127.0.0.1:{sim_port}"\n{more}'
        f'[zenoh]\nlisten = ["{endpoint}"]\n{zenoh}')
    daemon = running.start(a_dir, "run", "--config", "rover.toml")
    daemon.wait_for("publishing on Zenoh")
    bus = running.keep(open_bus(ZenohSettings(mode="client", listen=(), connect=(endpoint,))))
    return daemon, bus, Received(bus, key("rover", "session"),
                                 lambda p: messages.parse(p, "session"))


@pytest.mark.slow
def test_a_remote_solver_fetches_the_recording_through_the_router_and_solves_it(
        tmp_path: Path, running: Running) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router_dir, a_dir, b_dir = tmp_path / "router", tmp_path / "A", tmp_path / "B"
    router_dir.mkdir()
    (router_dir / "router.toml").write_text(
        f'listen = ["{endpoint}"]\n[access]\nenabled = true\nlocal = true\n')
    router = running.start(router_dir, "router", "--config", "router.toml")
    router.wait_for("router listening")
    # the station: a flight long enough for the solver to start while it flies
    demo = running.start(a_dir, "demo", "--station", "rover", "--no-view", "--no-base",
                         "--flight", "120",
                         "--speed", "6", "--seed", "6", "--out-dir", "flights",
                         "--zenoh-listen", endpoint, "--serve-after", "300")
    demo.wait_for("is taken: joined it")  # the router holds the endpoint
    truth_path = _until(lambda: next((a_dir / "flights").glob("*.truth.json"), None),
                        "the demo's truth file")
    base_path = next((a_dir / "flights").glob("*_base.ubx"))
    truth = json.loads(truth_path.read_text())
    # the base station's stream reaches the solver's machine by other means (base pairing
    # over the bus is another change): a copy in B
    (b_dir / "base").mkdir(parents=True)
    shutil.copy(base_path, b_dir / "base" / base_path.name)
    xyz = ", ".join(f"{v:.4f}" for v in truth["base"]["ecef_m"])
    (b_dir / "solver.toml").write_text(
        f'out_root = "{b_dir / "solutions"}"\nrecording_roots = ["{b_dir / "flights"}"]\n'
        'report_pdf = false\n'
        f'[zenoh]\nconnect = ["{endpoint}"]\nlisten = []\n'
        f'[stations.rover]\nbase = "{b_dir / "base"}/{{stem}}_base.ubx"\n'
        f'base_xyz = [{xyz}]\nlever_arm = [0.16, -0.03, 0.57]\n')
    bus = running.keep(open_bus(ZenohSettings(mode="client", listen=(), connect=(endpoint,))))
    sols = Received(bus, key("*", "solution"))
    solver = running.start(b_dir, "solver", "--config", "solver.toml")
    solver.wait_for("listening on groundstation/*/session")

    # the flight ends; the daemon announces the finished file with its SHA-256 and serves it
    demo.wait_for("serving 1 recording file(s)")
    final = _until(lambda: _final(sols), "a final solution")
    assert final["status"] == "ok", (final, solver.stderr())
    (mcap,) = (a_dir / "flights").glob("rover_*.mcap")
    fetched = b_dir / "solutions" / "rover" / mcap.name
    assert final["flight"] == str(fetched)
    assert fetched.read_bytes() == mcap.read_bytes()
    assert sha256_file(fetched) == sha256_file(mcap)
    assert not fetched.with_name(fetched.name + ".part").exists()
    assert "SHA-256 verified" in solver.stderr()
    n_marks = len(truth["exposures"])
    assert final["counts"]["marks"] == n_marks
    assert final["quality"]["fixed_fraction"] > 0.9
    assert Path(final["out_dir"]).parent == b_dir / "solutions" / "rover"
    assert not any(a_dir.rglob("cameras.csv"))  # nothing written on the station's side
    # the daemon saw its file sent in full and stopped serving by itself
    demo.wait_for("every recording file was sent in full")
    assert demo.proc.wait(timeout=60) == 0, demo.stderr()

    # a late joiner asks for the latest solution
    replies = bus.get(key("rover", "q/solution"), timeout_s=10.0)
    late = [decode(p) for _, p in replies]
    assert [m["status"] for m in late] == ["ok"]
    assert late[0]["flight"] == str(fetched) and late[0]["counts"] == final["counts"]
    assert "Traceback" not in solver.stderr() + demo.stderr() + router.stderr()


@pytest.mark.slow
def test_each_rotated_part_is_served_while_the_daemon_records(
        tmp_path: Path, running: Running) -> None:
    """``groundstation run`` on the simulator's TCP stream, a new file every 5 s: each closed
    part appears in ``recordings[]`` and is fetched byte-identical while the daemon goes on
    recording; the part being written is refused."""
    from groundstation.solve.fetch import Fetcher, remote_for
    from groundstation.storage import transfer

    a_dir = tmp_path / "A"
    daemon, bus, sessions = _rover_on_simulator(running, tmp_path,
                                                more="[recorder]\nrotate_duration_s = 5\n")
    msg = _until(lambda: sessions.all(lambda m: m.get("recordings")),
                 "a session message listing a closed part", 60)[0]
    assert msg["state"] == "started"
    first = msg["recordings"][0]
    assert first["name"] == Path(msg["files"][0]).name
    assert len(msg["files"]) >= 2  # the part being written is listed, not served
    current = Path(msg["files"][-1]).name
    assert current not in {r["name"] for r in msg["recordings"]}
    remote = remote_for("rover", msg, Path(msg["files"][0]), tmp_path / "B", None)
    assert remote is not None
    # asked at once: the part being written has most of its 5 s ahead of it
    refused = bus.ask(remote.key_expr, transfer.Request(current, 0, 10).parameters())()
    assert len(refused) == 1 and refused[0].error
    assert b"not a finished file" in refused[0].payload
    got = Fetcher(bus).fetch(remote)
    on_disk = a_dir / "flights" / first["name"]
    assert got.read_bytes() == on_disk.read_bytes()
    assert sha256_file(on_disk) == first["sha256"]
    assert daemon.proc.poll() is None  # still recording


@pytest.mark.slow
def test_after_the_session_the_daemon_serves_until_told_to_stop(
        tmp_path: Path, running: Running) -> None:
    """``run`` with ``duration_s`` and ``serve_after_s``: the session ends, the last file is
    announced ``finished`` with its SHA-256 and served; nobody fetches it, so the daemon
    waits, and a SIGTERM then ends it at once, cleanly."""
    a_dir = tmp_path / "A"
    daemon, _, sessions = _rover_on_simulator(running, tmp_path, top="duration_s = 4\n",
                                              zenoh="serve_after_s = 600\n")
    daemon.wait_for("serving 1 recording file(s) for up to 600 s")
    msg = _until(lambda: sessions.all(lambda m: m.get("state") == "finished"),
                 "the finished session message", 30)[0]
    (mcap,) = (a_dir / "flights").glob("rover_*.mcap")
    assert msg["recordings"] == [{"name": mcap.name, "size": mcap.stat().st_size,
                                  "sha256": sha256_file(mcap), "chunk_bytes": 262144}]
    assert daemon.proc.poll() is None  # still serving: nobody fetched it
    daemon.proc.send_signal(signal.SIGTERM)
    assert daemon.proc.wait(timeout=20) == 0, daemon.stderr()
    assert "Traceback" not in daemon.stderr()


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl CLI")
def test_over_mutual_tls_a_solver_fetches_and_another_station_cannot(
        tmp_path: Path, running: Running) -> None:
    """The same through a router that admits by certificate only (mutual TLS, access control,
    no loopback exception): the rover daemon (``run``, certificate ``rover``) serves its
    recording, the solver (certificate ``solver``) fetches, verifies and solves it; a party
    with the ``base`` station's certificate is not answered when it asks for the rover's
    recording."""
    from test_router_tls import make_ca

    from groundstation.storage import transfer

    ca = make_ca(tmp_path / "ca")
    tls_port, sim_port = free_port(), free_port()
    tls = f"tls/localhost:{tls_port}"
    router_dir, a_dir, b_dir = tmp_path / "router", tmp_path / "A", tmp_path / "B"
    router_dir.mkdir()
    (router_dir / "router.toml").write_text(
        f'listen = ["tls/127.0.0.1:{tls_port}"]\n[tls]\nca = "{ca / "ca.pem"}"\n'
        f'certificate = "{ca / "router.pem"}"\nprivate_key = "{ca / "router.key"}"\n'
        'mtls = true\n[access]\nenabled = true\nlocal = false\nsolvers = ["solver"]\n'
        '[stations.rover]\n[stations.base]\n')

    def tls_zenoh(name: str) -> str:
        return (f'[zenoh]\nmode = "client"\nlisten = []\nconnect = ["{tls}"]\n'
                f'tls_ca = "{ca / "ca.pem"}"\ntls_certificate = "{ca / f"{name}.pem"}"\n'
                f'tls_private_key = "{ca / f"{name}.key"}"\n')

    def as_party(name: str) -> Bus:
        return open_bus(ZenohSettings(mode="client", listen=(), connect=(tls,),
                                      tls_ca=ca / "ca.pem", tls_certificate=ca / f"{name}.pem",
                                      tls_private_key=ca / f"{name}.key"))

    router = running.start(router_dir, "router", "--config", "router.toml")
    router.wait_for("router listening")
    (b_dir / "base").mkdir(parents=True)
    base = b_dir / "base" / "base.ubx"  # the base's stream, on the solver's side
    truth_path = tmp_path / "truth.json"
    running.start(tmp_path / "sim", "simulate", "--tcp", str(sim_port), "--duration", "120",
                  "--speed", "6", "--seed", "6", "--faults", "default", "--base-out", str(base),
                  "--truth", str(truth_path))
    # truth and base are written before it listens
    _until(lambda: "listening on tcp://" in (tmp_path / "sim" / "stdout.txt").read_text(),
           "the simulator listening")
    truth = json.loads(truth_path.read_text())
    xyz = ", ".join(f"{v:.4f}" for v in truth["base"]["ecef_m"])
    (b_dir / "solver.toml").write_text(
        f'out_root = "{b_dir / "solutions"}"\nrecording_roots = ["{b_dir / "flights"}"]\n'
        f'base = "{base}"\nbase_xyz = [{xyz}]\nreport_pdf = false\n' + tls_zenoh("solver"))
    observer = running.keep(as_party("solver"))
    sols = Received(observer, key("*", "solution"))
    solver = running.start(b_dir, "solver", "--config", "solver.toml")
    solver.wait_for("listening on groundstation/*/session")
    a_dir.mkdir()
    (a_dir / "rover.toml").write_text(
        f'station = "rover"\nduration_s = 26\n[source]\naddress = "127.0.0.1:{sim_port}"\n'
        + tls_zenoh("rover") + "serve_after_s = 300\n")
    daemon = running.start(a_dir, "run", "--config", "rover.toml")
    daemon.wait_for("serving 1 recording file(s)")
    (mcap,) = (a_dir / "flights").glob("rover_*.mcap")
    info = reading.part_info(mcap)  # the id carries a random token the name does not
    assert info is not None
    sid = info.session_id
    # a solver's certificate is answered; another station's is not (the router drops it)
    selector = f"groundstation/rover/q/recording/{sid}"
    params = transfer.Request(mcap.name, 0, 1000).parameters()
    (answer,) = observer.ask(selector, params, 5.0)()
    assert not answer.error and answer.payload == mcap.read_bytes()[:1000]
    intruder = running.keep(as_party("base"))
    _until(lambda: intruder.connections() > 0, "the intruder connected", 30)
    for _ in range(3):
        assert intruder.ask(selector, params, 1.0)() == []

    final = _until(lambda: _final(sols), "a final solution")
    assert final["status"] == "ok", (final, solver.stderr())
    fetched = b_dir / "solutions" / "rover" / mcap.name
    assert final["flight"] == str(fetched)
    assert fetched.read_bytes() == mcap.read_bytes()
    assert final["counts"]["marks"] == len(truth["exposures"])
    daemon.wait_for("every recording file was sent in full")
    late = [decode(p) for _, p in observer.get(key("rover", "q/solution"), 10.0)]
    assert [m["status"] for m in late] == ["ok"]
    assert "Traceback" not in solver.stderr() + daemon.stderr() + router.stderr()
