"""Recordings over Zenoh, the two ends in one process on a real Zenoh link (loopback, free
port): the daemon's :class:`RecordingServer` serving a real MCAP written by the session
recorder, and the solver's :class:`Fetcher` on another session. A link that stops answering
mid-fetch, a damaged chunk, a corrupted ``.part`` and crafted queries."""

from __future__ import annotations

import random
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest
from peers import cli_env, free_port, wait_until

from groundstation import messages
from groundstation.bus import Bus, Reply, encode, open_bus
from groundstation.config import ZenohSettings
from groundstation.errors import GroundstationError
from groundstation.live.serve import RecordingServer
from groundstation.solve.fetch import Fetcher, Remote, remote_for
from groundstation.storage import transfer
from groundstation.storage.session import SessionRecorder

# One worker runs this module's tests (pytest-xdist):
# its module fixture records a flight, made once.
pytestmark = pytest.mark.xdist_group("test_recording_fetch")

CHUNK = 64 * 1024


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A finished MCAP of about 1.5 MB of raw chunks (incompressible: random bytes), and its
    session id."""
    d = tmp_path_factory.mktemp("served")
    rng = random.Random(7)
    rec = SessionRecorder(d, "rover", chunk_size_bytes=64 * 1024, compression="none",
                          sidecar=True)
    rec.open()
    t = 1_700_000_000_000_000_000
    for i in range(1500):
        rec.write_raw(rng.randbytes(1000), t + i * 10_000_000)
    rec.close()
    (path,) = rec.stats.files
    return path, rec.session_id


class Link:
    """A serving bus and a fetching bus joined on loopback; ``answer`` may be wrapped."""

    def __init__(self, station: Bus | None = None, solver: Bus | None = None) -> None:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.station_bus: Bus = station or open_bus(ZenohSettings(listen=(endpoint,)))
        self.solver_bus: Bus = solver or open_bus(ZenohSettings(
            mode="client", listen=(), connect=(endpoint,)))
        self.server = RecordingServer("rover", chunk_bytes=CHUNK)
        self.asked: list[tuple[str, dict[str, str | None]]] = []
        self.mute_from: int | None = None  # no reply from this offset on (the link is down)
        self.damage: set[int] = set()  # offsets whose reply has one byte flipped (once)
        self.answered = 0
        self._lock = threading.Lock()
        self.station_bus.answer(self.server.key_expr, self._answer)

    def _answer(self, query_key: str, params: Mapping[str, str | None]) -> list[Reply]:
        with self._lock:
            self.asked.append((query_key, dict(params)))
            offset = int(params.get("offset") or 0) if (params.get("offset") or "").isdigit() else 0
            if self.mute_from is not None and offset >= self.mute_from:
                return []  # the query ends without a reply, as when the link is down
            self.answered += 1
        replies = self.server.answer(query_key, params)
        if offset in self.damage and replies and not replies[0].error:
            self.damage.discard(offset)
            r = replies[0]
            bad = bytes([r.payload[0] ^ 0xFF]) + r.payload[1:]
            replies = [Reply(r.key, bad, r.attachment)]
        return replies

    def ready(self, remote: Remote) -> None:
        """Wait until the queryable is known to the fetching side."""
        req = transfer.Request(remote.name, 0, 1)
        wait_until(lambda: any(not r.error for r in self.solver_bus.ask(
            remote.key_expr, req.parameters(), 2.0)()), 15, "the queryable reachable")
        self.asked.clear()

    def close(self) -> None:
        self.solver_bus.close()
        self.station_bus.close()


@pytest.fixture
def link() -> Iterator[Link]:
    ln = Link()
    yield ln
    ln.close()


def _remote(link: Link, recording: tuple[Path, str], out: Path) -> Remote:
    path, sid = recording
    served = link.server.add(path, sid)
    assert served is not None
    body = {"state": "finished", "files": [str(path)], "session_id": sid,
            "recordings": link.server.entries()}
    msg = messages.parse(encode("session", body, station="rover"), "session")
    remote = remote_for("rover", msg, path, out, None)
    assert remote is not None and remote.dest == out / "rover" / path.name
    link.ready(remote)
    return remote


def _fast(s: float) -> None:
    time.sleep(min(s, 0.05))


def test_fetch_is_byte_identical_with_a_window_of_queries(
        link: Link, recording: tuple[Path, str], tmp_path: Path) -> None:
    path, _ = recording
    remote = _remote(link, recording, tmp_path / "out")
    assert remote.size == path.stat().st_size > 20 * CHUNK
    fetcher = Fetcher(link.solver_bus, window=8)
    got = fetcher.fetch(remote)
    assert got.read_bytes() == path.read_bytes()
    assert transfer.sha256_file(got) == remote.sha256
    assert not got.with_name(got.name + ".part").exists()
    offsets = [int(p["offset"] or 0) for _, p in link.asked]
    # each chunk asked once (Zenoh may hand queries in flight to the server in any order)
    assert sorted(offsets) == list(range(0, remote.size, CHUNK))
    assert fetcher.retries == 0 and fetcher.bad_chunks == 0
    assert link.server.sent_in_full()


def test_a_link_that_goes_quiet_mid_fetch_resumes_at_the_part_size(
        link: Link, recording: tuple[Path, str], tmp_path: Path) -> None:
    path, _ = recording
    remote = _remote(link, recording, tmp_path / "out")
    part = remote.dest.with_name(remote.name + ".part")
    link.mute_from = 7 * CHUNK
    with pytest.raises(GroundstationError, match=r"no chunk from station rover .* kept in"):
        Fetcher(link.solver_bus, stall_s=1.0, sleep=_fast).fetch(remote)
    assert part.stat().st_size == 7 * CHUNK  # every chunk answered was kept, nothing more
    assert not remote.dest.exists()
    # the link is back: a new fetch (a restarted solver) starts where the .part ends
    link.mute_from = None
    link.asked.clear()
    fetcher = Fetcher(link.solver_bus)
    got = fetcher.fetch(remote)
    assert fetcher.resumed_at == 7 * CHUNK
    assert min(int(p["offset"] or 0) for _, p in link.asked) == 7 * CHUNK
    assert got.read_bytes() == path.read_bytes()


def test_the_link_returning_within_the_stall_bound_needs_no_second_fetch(
        link: Link, recording: tuple[Path, str], tmp_path: Path) -> None:
    path, _ = recording
    remote = _remote(link, recording, tmp_path / "out")
    link.mute_from = 5 * CHUNK
    threading.Timer(0.5, lambda: setattr(link, "mute_from", None)).start()
    fetcher = Fetcher(link.solver_bus, stall_s=30.0, sleep=_fast)
    got = fetcher.fetch(remote)
    assert fetcher.retries > 0
    assert got.read_bytes() == path.read_bytes()


def test_a_damaged_chunk_is_refused_by_its_crc_and_asked_again(
        link: Link, recording: tuple[Path, str], tmp_path: Path) -> None:
    path, _ = recording
    remote = _remote(link, recording, tmp_path / "out")
    link.damage = {3 * CHUNK}
    fetcher = Fetcher(link.solver_bus, sleep=_fast)
    got = fetcher.fetch(remote)
    assert fetcher.bad_chunks == 1 and fetcher.discarded == 0
    offsets = [int(p["offset"] or 0) for _, p in link.asked]
    assert offsets.count(3 * CHUNK) == 2
    assert got.read_bytes() == path.read_bytes()


def test_a_corrupted_part_is_caught_by_the_sha256_and_fetched_again(
        link: Link, recording: tuple[Path, str], tmp_path: Path) -> None:
    path, _ = recording
    remote = _remote(link, recording, tmp_path / "out")
    part = remote.dest.with_name(remote.name + ".part")
    part.parent.mkdir(parents=True)
    good = path.read_bytes()[: 5 * CHUNK]
    part.write_bytes(good[:1000] + bytes([good[1000] ^ 0x01]) + good[1001:])  # one bit off
    fetcher = Fetcher(link.solver_bus)
    got = fetcher.fetch(remote)
    assert fetcher.resumed_at == 0  # the second attempt started over
    assert fetcher.discarded == 1
    assert got.read_bytes() == path.read_bytes()
    # a .part longer than the file is not trusted either
    got.unlink()
    part.write_bytes(b"x" * (remote.size + 1))
    assert Fetcher(link.solver_bus).fetch(remote).read_bytes() == path.read_bytes()


def test_crafted_queries_are_refused_counted_and_read_nothing(
        link: Link, recording: tuple[Path, str], tmp_path: Path) -> None:
    path, sid = recording
    secret = path.parent / "secret.mcap"
    secret.write_bytes(b"not yours")
    outside = path.parent.parent / "x"
    outside.write_bytes(b"not yours either")
    remote = _remote(link, recording, tmp_path / "out")
    name = path.name
    sent_before = link.server.sent_bytes  # the readiness probe's one byte
    bad = [
        (sid, {"file": "../x", "offset": "0", "length": "10"}),
        (sid, {"file": f"../{path.parent.name}/{name}", "offset": "0", "length": "10"}),
        (sid, {"file": str(path), "offset": "0", "length": "10"}),
        (sid, {"file": "secret.mcap", "offset": "0", "length": "10"}),  # in the dir, not served
        (sid, {"file": name, "offset": "-1", "length": "10"}),
        (sid, {"file": name, "offset": "1e3", "length": "10"}),
        (sid, {"file": name, "offset": str(remote.size + 1), "length": "10"}),
        (sid, {"file": name, "offset": "0", "length": str(1 << 40)}),
        (sid, {"file": name, "offset": "0", "length": "0"}),
        (sid, {"file": name, "offset": "0"}),
        ("rover_19990101T000000Z", {"file": name, "offset": "0", "length": "10"}),
    ]
    for session_id, params in bad:
        replies = link.solver_bus.ask(f"groundstation/rover/q/recording/{session_id}",
                                      params, 5.0)()
        assert len(replies) == 1 and replies[0].error, (params, replies)
        text = replies[0].payload.decode()
        assert text.startswith("refused: ") and "not yours" not in text
    assert link.server.refused == len(bad)
    assert link.server.sent_bytes == sent_before
    # the last byte, and an offset at the very end (nothing left) are fine
    (last,) = link.solver_bus.ask(remote.key_expr, {"file": name, "offset": str(
        remote.size - 1), "length": "10"}, 5.0)()
    assert not last.error and last.payload == path.read_bytes()[-1:]


def test_a_file_still_being_written_is_not_served(
        link: Link, recording: tuple[Path, str], tmp_path: Path) -> None:
    path, sid = recording
    link.server.session_id = sid  # the session is known; its file is not finished yet
    req = transfer.Request(path.name, 0, 10)

    def refused() -> bool:
        replies = link.solver_bus.ask(f"groundstation/rover/q/recording/{sid}",
                                      req.parameters(), 2.0)()
        return bool(replies) and replies[0].error and b"not a finished file" in replies[0].payload

    wait_until(refused, 15, "a refusal for the unfinished file")
    assert link.server.sent_bytes == 0


def test_session_message_recordings_are_checked() -> None:
    good = {"name": "rover_20261122T200000Z.mcap", "size": 10, "sha256": "a" * 64,
            "chunk_bytes": CHUNK}
    body = {"state": "finished", "files": [], "session_id": "s", "recordings": [good]}
    messages.parse(encode("session", body, station="rover"), "session")
    for bad in ({**good, "name": "../x.mcap"}, {**good, "name": "/etc/x.mcap"},
                {**good, "size": -1}, {**good, "sha256": "zz"},
                {**good, "chunk_bytes": 1 << 30}, "rover.mcap"):
        with pytest.raises(messages.BadMessage):
            messages.parse(encode("session", {**body, "recordings": [bad]}, station="rover"),
                           "session")


def _router(cwd: Path, endpoint: str) -> subprocess.Popen[bytes]:
    cwd.mkdir(parents=True, exist_ok=True)
    return subprocess.Popen([sys.executable, "-m", "groundstation.cli", "router", "--listen",
                             endpoint], cwd=cwd, env=cli_env(), stdout=subprocess.DEVNULL,
                            stderr=(cwd / "stderr.txt").open("ab"))


@pytest.mark.slow
def test_the_router_killed_and_restarted_mid_fetch_is_resumed(
        recording: tuple[Path, str], tmp_path: Path) -> None:
    """A real broken link: both ends are clients of a router process that is killed while
    the fetch is half done (held there by answering no further chunk until then), and
    started again on the same port; the sessions reconnect by themselves and the fetch goes
    on from the ``.part`` without being started again."""
    path, _ = recording
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = _router(tmp_path / "router", endpoint)
    client = ZenohSettings(mode="client", listen=(), connect=(endpoint,))
    link: Link | None = None
    try:
        wait_until(lambda: _can_open(client), 30, "the router up")
        link = Link(station=open_bus(client), solver=open_bus(client))
        remote = _remote(link, recording, tmp_path / "out")
        part = remote.dest.with_name(remote.name + ".part")
        link.mute_from = 9 * CHUNK
        fetcher = Fetcher(link.solver_bus, stall_s=60.0, query_timeout_s=2.0)
        result: list[Path | BaseException] = []

        def run() -> None:
            try:
                result.append(fetcher.fetch(remote))
            except BaseException as err:  # handed to the test thread
                result.append(err)

        worker = threading.Thread(target=run, daemon=True)
        worker.start()
        wait_until(lambda: part.exists() and part.stat().st_size == 9 * CHUNK, 30,
                   "half the file fetched")
        router.kill()
        router.wait(timeout=10)
        link.mute_from = None  # the station would answer now, but there is no link
        time.sleep(1.0)  # a real outage: queries meanwhile go nowhere
        assert not result and part.stat().st_size == 9 * CHUNK
        router = _router(tmp_path / "router", endpoint)
        worker.join(timeout=90)
        assert result and isinstance(result[0], Path), result
        assert result[0].read_bytes() == path.read_bytes()
        assert fetcher.retries > 0 and fetcher.discarded == 0
    finally:
        if link is not None:
            link.close()
        router.kill()
        router.wait(timeout=10)


def _can_open(settings: ZenohSettings) -> bool:
    try:
        bus = open_bus(settings)
    except GroundstationError:
        return False
    ok = bus.connections() > 0
    bus.close()
    return ok
