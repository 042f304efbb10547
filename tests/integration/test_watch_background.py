"""``groundstation watch &``: started in the background of a real terminal, the watch runs on
(it is not stopped by SIGTTOU for touching the terminal's modes) and says once that its keys are
off until it is in the foreground.

The terminal is a real pty whose session leader stands in for an interactive shell: it owns the
foreground process group and starts the watch in a process group of its own, as ``cmd &`` in a
job-control shell does, then waits for it the way a shell does (``WUNTRACED``: a stopped child
is reported, not waited for forever). The watch reads a real Zenoh router on loopback.
"""

from __future__ import annotations

import os
import pty
import signal
import sys
from pathlib import Path

from peers import REPO, Daemon, cli_env, free_port, read_terminal

from groundstation.view.watch import BACKGROUND_NOTE

SHELL = r"""
import os, signal, subprocess, sys
# the session leader of the pty (pty.fork): its group is the terminal's foreground group
assert os.tcgetpgrp(0) == os.getpgrp()
proc = subprocess.Popen(sys.argv[1:], process_group=0)  # "cmd &": a background group
_, status = os.waitpid(proc.pid, os.WUNTRACED)
if os.WIFSTOPPED(status):
    print(f"\nSHELL: stopped by signal {os.WSTOPSIG(status)}", flush=True)
    os.kill(proc.pid, signal.SIGKILL)
    os.waitpid(proc.pid, 0)
    sys.exit(3)
print(f"\nSHELL: exit {os.waitstatus_to_exitcode(status)}", flush=True)
"""


def test_watch_in_the_background_runs_and_says_keys_are_off(
    tmp_path: Path, daemons: list[Daemon],
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = Daemon("--listen", endpoint, command="router")
    daemons.append(router)
    router.wait_for(endpoint.removeprefix("tcp/"))
    argv = [sys.executable, "-c", SHELL, sys.executable, "-m", "groundstation.cli", "watch",
            "--station", "bg", "--connect", endpoint, "--duration", "3"]
    env = cli_env(TERM="xterm-256color", COLUMNS="100", LINES="30")
    pid, master = pty.fork()
    if pid == 0:  # the child: the session leader of the pty, in the repository
        os.chdir(REPO)
        os.execve(sys.executable, argv, env)
    try:
        screen = read_terminal(master, 60)
    finally:
        os.close(master)
        ended, status = os.waitpid(pid, os.WNOHANG)
        if ended == 0:  # still there after the deadline: end it (the assertions say why)
            os.kill(pid, signal.SIGKILL)
            _, status = os.waitpid(pid, 0)
    assert "SHELL: stopped" not in screen, screen[-2000:]
    assert "SHELL: exit 0" in screen, screen[-2000:]
    assert os.waitstatus_to_exitcode(status) == 0
    assert screen.count(BACKGROUND_NOTE) == 1, screen[-2000:]
    assert "groundstation watch · station bg" in screen
