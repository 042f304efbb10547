"""Several daemons on one machine with the same (default) Zenoh settings, all visible.

Separate processes in separate working directories, real Zenoh on loopback: ``groundstation
demo`` (simulator -> pty -> daemon) once per station, all with one and the same listen endpoint
(the default ``tcp/127.0.0.1:7447`` would collide with other tests running at the same time,
so a free port stands in for it, given identically to every daemon). The first daemon up
listens; the others find the endpoint taken and join it (``groundstation.bus``). ``watch`` and
the dashboard connect to that one endpoint and see every station. When the first daemon is
killed, one of the others takes the endpoint over and the rest join it: a new ``watch`` sees
them again.
"""

from __future__ import annotations

import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import pytest
from peers import CliProc, cli_env, free_port, wait_until

from groundstation import jsonio

WAIT_S = 60.0  # generous: the shared 2-core machine


def daemon(tmp: Path, station: str, endpoint: str) -> CliProc:
    # (--no-base: daemons of these stations only, not the demo's base stations beside them)
    return CliProc(tmp / station, "demo", "--station", station, "--no-view", "--no-base",
                   "--flight", "900", "--zenoh-listen", endpoint)


def watch_sees(tmp: Path, station: str, endpoint: str) -> bool:
    """A new ``watch --station`` process (own directory) shows the station's live status."""
    cwd = tmp / f"watch-{station}-{time.monotonic_ns()}"
    cwd.mkdir()
    out = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "watch", "--station", station,
         "--connect", endpoint, "--duration", "4"],
        cwd=cwd, env=cli_env(), capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 0, out.stderr
    return f"session {station}_" in out.stdout and "LINK" in out.stdout


def eventually(check: Callable[[], object]) -> None:
    """:func:`wait_until` with this module's generous timeout; polls at 0.5 s (some checks
    start a process)."""
    wait_until(check, WAIT_S, "eventually", poll_s=0.5)


def dashboard_stations(port: int) -> dict[str, bool]:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/stations", timeout=5) as r:
            doc = jsonio.loads(r.read())
    except OSError:
        return {}
    return {s["name"]: bool(s["alive"] and s["has_status"]) for s in doc}


@pytest.mark.slow
def test_daemons_with_the_same_settings_are_all_visible_and_survive_the_first(
        tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    procs: list[CliProc] = []
    try:
        rover = daemon(tmp_path, "rover", endpoint)
        procs.append(rover)
        rover.wait_for("publishing on Zenoh")
        base = daemon(tmp_path, "base", endpoint)
        spare = daemon(tmp_path, "spare", endpoint)
        procs += [base, spare]
        for p in (base, spare):
            p.wait_for("is taken: joined it")
            p.wait_for("publishing on Zenoh")
        assert "Traceback" not in base.stderr() and "os error" not in base.stderr()

        eventually(lambda: watch_sees(tmp_path, "base", endpoint))
        eventually(lambda: watch_sees(tmp_path, "rover", endpoint))

        web = free_port()
        dash = CliProc(tmp_path / "dashboard", "dashboard", "--port", str(web), "--connect",
                       endpoint, "--duration", "120")
        procs.append(dash)
        want = {"rover": True, "base": True, "spare": True}
        eventually(lambda: dashboard_stations(web) == want)

        rover.proc.kill()  # the meeting point goes, without saying goodbye
        rover.proc.wait(timeout=10)
        eventually(lambda: "took over" in base.stderr() + spare.stderr())
        taker, other = (base, spare) if "took over" in base.stderr() else (spare, base)
        assert "took over" not in other.stderr()  # one listener; the other joined it anew
        eventually(lambda: watch_sees(tmp_path, "base", endpoint))
        eventually(lambda: watch_sees(tmp_path, "spare", endpoint))
        # the dashboard (a client) reconnected by itself and still has both
        eventually(lambda: {k: v for k, v in dashboard_stations(web).items()
                            if k != "rover"} == {"base": True, "spare": True})
        assert taker.proc.poll() is None and other.proc.poll() is None
    finally:
        for p in procs:
            p.stop()


def test_a_joined_bus_takes_over_and_declares_again() -> None:
    from groundstation.bus import open_bus
    from groundstation.config import ZenohSettings

    settings = ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",))
    first, second = open_bus(settings), open_bus(settings)
    viewer = open_bus(ZenohSettings(mode="client", listen=(), connect=settings.listen))
    seen: list[tuple[str, bool]] = []
    try:
        assert not first.joined and second.joined
        second.liveliness_token("groundstation/base/alive")
        second.queryable("groundstation/base/q/status", lambda: [b"{}"])
        viewer.subscribe_liveliness("groundstation/*/alive", lambda k, up: seen.append((k, up)))
        eventually(lambda: ("groundstation/base/alive", True) in seen)
        first.close()
        eventually(lambda: not second.joined)  # it listens now
        eventually(lambda: seen[-1] == ("groundstation/base/alive", True)
                   and ("groundstation/base/alive", False) in seen)
        eventually(lambda: viewer.get("groundstation/base/q/status", 1.0)
                   == [("groundstation/base/q/status", b"{}")])
    finally:
        for b in (viewer, second, first):
            b.close()


@pytest.mark.slow
def test_an_endpoint_held_by_another_program_is_one_clear_line() -> None:
    import socket

    from groundstation.bus import open_bus
    from groundstation.config import ZenohSettings
    from groundstation.errors import GroundstationError

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()  # accepts, never speaks Zenoh
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
        try:
            open_bus(ZenohSettings(listen=(endpoint,)))
        except GroundstationError as err:
            text = str(err)
        else:
            raise AssertionError("joined a port that is not Zenoh")
    assert "is taken and joining it failed" in text
    assert "\n" not in text and ".rs:" not in text, text
