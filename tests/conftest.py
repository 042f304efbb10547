"""Shared fixtures: where the real recordings are (skipping cleanly when they are absent), and
what keeps every test to its own resources when the suite runs in parallel (pytest-xdist) on a
machine where other things run: no ``GROUNDSTATION_*`` variable of the caller, no session on
the default Zenoh endpoint, daemons killed before their pty is closed. Ports come from
:func:`peers.free_port` (a range per worker), directories from ``tmp_path``."""

from __future__ import annotations

import os
import re
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from once import DemoFlight, demo_flight_300
from peers import Daemon, Pty

from groundstation import bus
from groundstation.config import DEFAULT_ENDPOINT, ZenohSettings

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


ONE_WORKER = re.compile(r"\bpytest\.mark\.xdist_group\(")
"""How a test module asks for its tests to run on one worker, in its ``pytestmark`` (its module
fixture is expensive: made once, not once per worker)."""


def one_worker_modules(root: Path) -> frozenset[str]:
    """The test modules (paths from ``root``, as in node ids) that declare :data:`ONE_WORKER`."""
    return frozenset(p.relative_to(root).as_posix() for p in (root / "tests").rglob("test_*.py")
                     if ONE_WORKER.search(p.read_text(encoding="utf-8")))


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """``--dist loadgroup``, done here: xdist 3.8 groups by renaming each item's node id,
    which pytest 9.2 ignores (``nodeid`` is derived from ``_id``), so its groups were split
    across workers and their module fixtures made again on each. Here a module with
    ``pytest.mark.xdist_group(...)`` in its ``pytestmark`` is one unit of work (one worker,
    its module fixtures made once); every other test is a unit of its own. Units with the most
    tests are handed out first."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    grouped = one_worker_modules(config.rootpath)

    class ModuleGroups(LoadScopeScheduling):  # type: ignore[misc]
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if module in grouped else nodeid

    return ModuleGroups(config, log)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the checkout; tests that need it skip when it is absent."""
    if not (SHARED_DATA / "real").is_dir():
        pytest.skip(
            f"real recordings not available: {SHARED_DATA} is absent "
            "(a fresh clone has no ../shared)"
        )
    return SHARED_DATA


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C as a user sends it: a suite started where SIGINT is ignored (a background job of
    a script, nohup) passed that on to every command a test starts, and the tests that stop a
    demo, a solve or watch with SIGINT saw it ignored. A caught signal is reset by exec."""
    del config
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def _no_groundstation_environment() -> Iterator[None]:
    """The tests name every setting they mean: a ``GROUNDSTATION_*`` variable of the shell that
    runs them (a developer's station name, config file or Zenoh endpoint) changes none of
    them, in this process or in the commands it starts."""
    mp = pytest.MonkeyPatch()
    for name in [k for k in os.environ if k.startswith("GROUNDSTATION_")]:
        mp.delenv(name)
    yield
    mp.undo()


@pytest.fixture(autouse=True)
def _own_zenoh_endpoints(monkeypatch: pytest.MonkeyPatch) -> None:
    """No session opened in a test process listens on or connects to the default endpoint
    (``tcp/127.0.0.1:7447``): it belongs to whatever else runs on the machine (a demo, another
    test worker), and a test there would join it and see its stations. Every test takes its
    endpoints from :func:`peers.free_port`. (The commands a test starts are held to it by
    naming their endpoints; the suite was checked with a foreign listener on 7447.)"""
    real = bus.zenoh_config

    def own(settings: ZenohSettings, extra: dict[str, Any] | None = None) -> Any:
        if DEFAULT_ENDPOINT in (*settings.listen, *settings.connect):
            raise AssertionError(f"a test's Zenoh session on the default endpoint "
                                 f"{DEFAULT_ENDPOINT} (listen {list(settings.listen)}, connect "
                                 f"{list(settings.connect)}): name one of its own (free_port)")
        return real(settings, extra)

    monkeypatch.setattr(bus, "zenoh_config", own)


@pytest.fixture
def pty(tmp_path: Path) -> Iterator[Pty]:
    """A pty pair; the daemon opens it through a symlink that can be pulled and plugged.

    Closed after the test's daemons are killed (:func:`daemons` asks for it), and its link
    goes with it: the kernel gives a closed pty's number to the next pty opened on the
    machine, another test's, and a daemon still reopening this one would take that one
    ("in use by process N").
    """
    p = Pty(tmp_path / "ttyGS0")
    yield p
    p.close()


@pytest.fixture
def daemons(pty: Pty) -> Iterator[list[Daemon]]:
    """Daemon processes started by a test; killed at the end whatever happened, before the
    test's pty is closed (``pty`` is set up first, so it is torn down after)."""
    started: list[Daemon] = []
    yield started
    for d in started:
        d.kill()


@pytest.fixture(scope="session")
def demo_flight(tmp_path_factory: pytest.TempPathFactory) -> DemoFlight:
    """The demo flight of 300 s, seed 4, at full speed: made once for the whole run (every
    worker); its files are read-only."""
    return demo_flight_300(tmp_path_factory)
