"""Zenoh listens only where configured: clients (watch, dashboard, solver) nowhere by default.

The listening sockets of a process are read from ``/proc`` (its socket inodes in ``fd/`` that
are in LISTEN state in ``net/tcp``/``net/tcp6``), as ``ss -ltnp`` would show them. Zenoh's own
default for an empty listen list is ``tcp/[::]:0`` on every interface; the bus must not let it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from peers import cli_env, free_port

from groundstation.bus import open_bus
from groundstation.config import CLIENT_ZENOH, ZenohSettings

LISTEN = "0A"


def listening_ports(pid: int) -> set[int]:
    """TCP ports the process ``pid`` listens on."""
    inodes = set()
    try:
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue  # closed meanwhile
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
        tables = [Path(f"/proc/{pid}/net/{n}").read_text() for n in ("tcp", "tcp6")]
    except (FileNotFoundError, ProcessLookupError):
        return set()
    ports = set()
    for table in tables:
        for line in table.splitlines()[1:]:
            cols = line.split()
            if cols[3] == LISTEN and cols[9] in inodes:
                ports.add(int(cols[1].rsplit(":", 1)[1], 16))
    return ports


def test_a_client_session_listens_nowhere_and_a_listener_is_seen() -> None:
    before = listening_ports(os.getpid())
    port = free_port()
    client = open_bus(ZenohSettings(listen=(), connect=(f"tcp/127.0.0.1:{free_port()}",)))
    try:
        time.sleep(0.3)
        assert listening_ports(os.getpid()) == before
    finally:
        client.close()
    daemon_like = open_bus(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)))
    try:
        assert listening_ports(os.getpid()) - before == {port}  # the check sees a listener
    finally:
        daemon_like.close()


@pytest.mark.parametrize("argv", [
    ["watch", "--duration", "4"],
    ["dashboard", "--port", "0", "--duration", "4"],
    ["solver", "--duration", "4"],
], ids=lambda a: a[0])
def test_client_commands_listen_only_where_configured(argv: list[str], tmp_path: Path) -> None:
    assert CLIENT_ZENOH.listen == ()
    env = cli_env()
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nobody there: the client keeps trying
    proc = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", *argv, "--connect", endpoint],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    seen: set[int] = set()
    try:
        while proc.poll() is None:  # sampled for the whole run: the session opens early
            seen |= listening_ports(proc.pid)
            time.sleep(0.1)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    if argv[0] == "dashboard":  # the web page's own port, on loopback, and nothing else
        url = next(line for line in out.splitlines() if line.startswith("dashboard: "))
        assert seen == {int(url.rstrip("/").rsplit(":", 1)[1])}
    else:
        assert seen == set()
