"""A disk that fills up under the recorder: nothing received is lost within the bound, what is
beyond it is counted, the files stay readable, and recording resumes when space returns."""

from __future__ import annotations

import asyncio
import errno
import json
import os
import shutil
import time
from collections.abc import AsyncIterator
from pathlib import Path

from peers import EventCollector
from test_recorder import FakeClock, generated_stream

from groundstation.config import load_settings
from groundstation.live.daemon import Pipeline
from groundstation.records import Event
from groundstation.storage import iter_messages, iter_raw_chunks, read_metadata, read_summary
from groundstation.storage.mcapio import ExactFile, ReadReport
from groundstation.storage.reading import Recording
from groundstation.storage.session import SessionRecorder
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer


class Disk:
    """The fault hook: files whose writes fail with ENOSPC while ``full`` (after ``room`` more
    bytes, so the failing write is a short one, as on a real disk)."""

    def __init__(self) -> None:
        self.full = False
        self.room = 0
        self.failed_writes = 0

    def fill(self, room: int = 0) -> None:
        self.full, self.room = True, room

    def open(self, path: Path) -> ExactFile:
        return FlakyFile(path, self)


class FlakyFile(ExactFile):
    def __init__(self, path: Path, disk: Disk) -> None:
        self.disk = disk
        super().__init__(path)

    def _write_some(self, data: memoryview) -> int:
        if self.disk.full:
            if self.disk.room <= 0:
                self.disk.failed_writes += 1
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.path))
            n = min(len(data), self.disk.room)
            self.disk.room -= n
            return os.write(self.fileno(), data[:n])
        return super()._write_some(data)


def raw_of(paths: list[Path]) -> bytes:
    return b"".join(d for p in paths for d, _ in iter_raw_chunks(p))


def topics_of(paths: list[Path], topic: str) -> list[dict[str, object]]:
    return [json.loads(m.data) for p in paths for m in iter_messages(p, topics=(topic,))]


class Feeder:
    """Drives a SessionRecorder as the recorder sink would, with a fake clock."""

    def __init__(self, tmp_path: Path, disk: Disk, backlog_bytes_max: int = 64_000_000) -> None:
        self.clock = FakeClock()
        self.rec = SessionRecorder(tmp_path, "st1", chunk_size_bytes=512, clock=self.clock,
                                   flush_interval_ns=50_000_000, retry_interval_ns=500_000_000,
                                   open_file=disk.open, backlog_bytes_max=backlog_bytes_max)
        self.rec.open()
        self.framer = UbxFramer()
        self.decoder = Decoder()
        self.sent = bytearray()
        self.notices: list[Event] = []

    def feed(self, data: bytes, chunk: int = 97) -> None:
        for i in range(0, len(data), chunk):
            piece = data[i : i + chunk]
            t = self.clock()
            self.rec.write_raw(piece, t)
            self.sent += piece
            for frame in self.framer.feed(piece, t):
                self.rec.write_record(self.decoder.decode(frame), t)
            self.rec.maybe_flush()
            self.notices += self.rec.take_notices()

    def idle(self, seconds: float) -> None:
        self.clock.now += int(seconds * 1e9)
        self.rec.maybe_flush()
        self.notices += self.rec.take_notices()

    def kinds(self) -> list[str]:
        return [e.kind for e in self.notices]


def test_disk_full_then_space_again_loses_nothing(tmp_path: Path) -> None:
    disk = Disk()
    f = Feeder(tmp_path, disk)
    stream = generated_stream(n=2400)
    third = len(stream) // 3
    f.feed(stream[:third])
    disk.fill(room=333)  # the failing write is cut short
    f.feed(stream[third : 2 * third])
    assert f.kinds() == ["recorder.write_failed"]
    assert "No space left on device" in f.notices[0].message
    assert f.rec.failing and f.rec.stats.held_bytes > 0
    f.idle(1.0)  # a retry while the disk is still full leaves no new file behind
    assert disk.failed_writes >= 2
    assert len(list(tmp_path.glob("*.mcap"))) == len(list(tmp_path.glob("*.ubx"))) == 1
    disk.full = False
    f.idle(1.0)
    assert f.kinds() == ["recorder.write_failed", "recorder.recovered"]
    assert not f.rec.failing
    f.feed(stream[2 * third :])
    f.rec.close()
    stats = f.rec.stats
    assert (stats.dropped_raw_bytes, stats.dropped_records, stats.write_failures) == (0, 0, 1)
    mcaps, sides = list(stats.files), list(stats.sidecars)
    assert len(mcaps) == len(sides) == 2
    # every byte, in order, in the parts together; each sidecar is its part's /ubx/raw
    assert raw_of(mcaps) == bytes(f.sent) == stream
    assert b"".join(p.read_bytes() for p in sides) == stream
    for m, s in zip(mcaps, sides, strict=True):
        assert raw_of([m]) == s.read_bytes()
    # the abandoned part was cut back to a chunk boundary: readable, no torn chunk, no summary
    report = ReadReport()
    assert list(iter_messages(mcaps[0], report=report))
    assert read_summary(mcaps[0]) is None and read_summary(mcaps[1]) is not None
    meta = read_metadata(mcaps[1])["groundstation"]
    assert meta["previous_file"] == mcaps[0].name and meta["part"] == "2"
    assert "No space left on device" in meta["after_write_failure"]
    # decoded records: each time mark exactly once, in order, across the parts
    counts = [m["count"] for m in topics_of(mcaps, "/gnss/timemark")]
    assert counts == list(range(len(counts))) and len(counts) == 600


def test_beyond_the_bound_records_go_first_then_new_raw_bytes_counted(tmp_path: Path) -> None:
    disk = Disk()
    f = Feeder(tmp_path, disk, backlog_bytes_max=20_000)
    stream = generated_stream(n=2400)
    f.feed(stream[:5000])
    disk.fill()
    held_part = stream[5000:40_000]  # 35 kB: more than the bound
    f.feed(held_part)
    stats = f.rec.stats
    assert stats.dropped_records > 0 and stats.dropped_raw_bytes > 0
    assert stats.held_bytes <= 20_000
    drops = [e for e in f.notices if e.kind == "recorder.dropped"]
    assert len(drops) == 1  # the first at once, the next not before 10 s
    assert drops[0].message.startswith("recording backlog full (20 kB held): dropped ")
    assert drops[0].data["dropped_records"] == 1  # records go first
    disk.full = False
    f.idle(1.0)
    rec_ev = next(e for e in f.notices if e.kind == "recorder.recovered")
    assert "were dropped" in rec_ev.message
    f.feed(stream[40_000:])
    f.rec.close()
    stats = f.rec.stats
    got = raw_of(list(stats.files))
    assert b"".join(p.read_bytes() for p in stats.sidecars) == got
    # what is missing is exactly the counted bytes, and one contiguous hole (new chunks dropped)
    assert len(got) == len(stream) - stats.dropped_raw_bytes
    kept = len(stream) - stats.dropped_raw_bytes - (len(stream) - 40_000)
    assert got == stream[:kept] + stream[kept + stats.dropped_raw_bytes :]
    assert stats.dropped_raw_bytes == len(stream) - len(got)
    assert rec_ev.data["dropped_raw_bytes"] == stats.dropped_raw_bytes


def test_a_large_backlog_drains_in_slices_and_survives_a_new_failure(tmp_path: Path) -> None:
    disk = Disk()
    f = Feeder(tmp_path, disk)
    stream = generated_stream(n=2400)
    f.feed(stream)
    disk.fill()
    f.feed(stream * 40, chunk=1000)  # 2.9 MB of raw bytes and 7 MB of records, held
    held = f.rec.stats.held_bytes
    assert held > 5_000_000
    disk.full = False
    f.idle(1.0)  # a new part with the first slice of the backlog; the rest still held
    assert f.rec.failing and 0 < held - f.rec.stats.held_bytes <= 1_100_000
    f.feed(stream[:5000], chunk=5000)  # data arriving while draining goes behind the backlog
    f.idle(0.01)
    disk.fill(room=50)  # full again in the middle of the drain
    f.idle(0.01)
    assert f.rec.failing
    disk.full = False
    for _ in range(20):
        f.idle(0.6)
        if not f.rec.failing:
            break
    assert not f.rec.failing
    f.feed(stream[5000:10_000])
    f.rec.close()
    stats = f.rec.stats
    assert stats.write_failures == 1 and stats.dropped_raw_bytes == 0
    # the first, the part abandoned mid-drain, the last (rotated once more: 512-byte chunks)
    assert len(stats.files) >= 3
    assert raw_of(list(stats.files)) == bytes(f.sent) == stream * 41 + stream[:10_000]
    for m, side in zip(stats.files, stats.sidecars, strict=True):
        assert raw_of([m]) == side.read_bytes()
    assert [e.kind for e in f.notices] == ["recorder.write_failed", "recorder.recovered"]


def test_stopping_while_the_disk_is_full_never_raises(tmp_path: Path) -> None:
    disk = Disk()
    f = Feeder(tmp_path, disk)
    stream = generated_stream(n=400)
    f.feed(stream[:3000])
    f.rec.flush()
    disk.fill(room=10)
    f.feed(stream[3000:])
    f.rec.close()  # logged as lost, not raised
    (mcap,) = f.rec.stats.files
    assert stream.startswith(raw_of([mcap]))
    assert len(raw_of([mcap])) >= 3000
    assert f.rec.stats.sidecars[0].read_bytes() == raw_of([mcap])


class ChunkSource:
    """An in-process radio: chunks at a steady pace, the disk filled and emptied meanwhile."""

    name = "test"
    can_wait = False

    def __init__(self, data: bytes, disk: Disk) -> None:
        self.data = data
        self.disk = disk

    async def chunks(self) -> AsyncIterator[tuple[bytes, int]]:
        starts = range(0, len(self.data), 500)
        for k, i in enumerate(starts):
            if k == len(starts) // 4:
                self.disk.fill(room=100)
            if k == 3 * len(starts) // 4:
                self.disk.full = False
            await asyncio.sleep(0.01)
            yield self.data[i : i + 500], time.time_ns()
        await asyncio.sleep(0.5)


def test_daemon_pipeline_alerts_disk_full_and_clears_it(tmp_path: Path) -> None:
    from groundstation.live.fanout import Overflow

    disk = Disk()
    settings = load_settings(environ={}, overrides={
        "source": {"path": str(tmp_path / "unused.ubx")},
        "recorder": {"out_dir": str(tmp_path / "out"), "retry_s": 0.2, "flush_interval_s": 0.1},
        "zenoh": {"enabled": False},
    })
    stream = generated_stream(n=2400)
    events = EventCollector()
    pipeline = Pipeline(settings, source=ChunkSource(stream, disk), open_file=disk.open)
    pipeline.add_sink(events, 10_000, Overflow.NEVER_DROP)
    summary = asyncio.run(pipeline.run())
    assert raw_of(list(summary.files)) == stream
    assert b"".join(p.read_bytes() for p in summary.sidecars) == stream
    kinds = [(e.kind, e.data.get("alert")) for e in events.items
             if e.kind.startswith(("recorder.", "alert."))]
    assert ("recorder.write_failed", None) in kinds
    assert kinds.index(("alert.raised", "disk_full")) < kinds.index(("recorder.recovered", None))
    assert ("alert.cleared", "disk_full") in kinds
    opened = [e for e in events.items if e.kind == "recorder.file_opened"]
    assert [e.data["path"] for e in opened] == [str(p) for p in summary.files]
    # the events about the failure are themselves in the recording (held, then written)
    recorded = {str(e["kind"]) for e in topics_of(list(summary.files), "/groundstation/event")}
    assert {"recorder.write_failed", "alert.raised", "recorder.recovered"} <= recorded


def test_a_long_session_rotates_by_chunk_count_keeping_every_byte(tmp_path: Path) -> None:
    clock = FakeClock()
    rec = SessionRecorder(tmp_path, "st1", chunk_size_bytes=65536, clock=clock,
                          flush_interval_ns=1, max_chunks_per_file=5)
    rec.open()
    stream = generated_stream(n=400)
    for i in range(0, len(stream), 200):
        rec.write_raw(stream[i : i + 200], clock())
        rec.maybe_flush()  # one chunk per chunk of bytes, as in a slow live session
    rec.close()
    files = list(rec.stats.files)
    assert len(files) == -(-len(range(0, len(stream), 200)) // 5)
    assert raw_of(files) == stream
    assert b"".join(p.read_bytes() for p in rec.stats.sidecars) == stream
    assert all(read_summary(p) is not None for p in files)


def test_packed_chunk_indexes_write_the_same_file(tmp_path: Path) -> None:
    from groundstation.storage.mcapio import RAW_TOPIC, ChannelSpec, McapFileWriter

    spec = ChannelSpec(RAW_TOPIC, "ubx")
    stream = generated_stream(n=400)
    files = []
    for packed in (True, False):
        path = tmp_path / f"packed_{packed}.mcap"
        w = McapFileWriter(path, chunk_size_bytes=4096, packed_index=packed)
        assert (w.chunk_indexes is not None) == packed
        for i in range(0, len(stream), 300):
            w.add(spec, stream[i : i + 300], 1_000 + i, 1_000 + i)
            if i % 1200 == 0:
                w.flush()
        if packed:
            assert w.chunk_indexes is not None and len(w.chunk_indexes) > 5
            assert w.chunk_indexes.nbytes / len(w.chunk_indexes) < 200
        w.finish()
        files.append(path.read_bytes())
    assert files[0] == files[1]
    summary = read_summary(tmp_path / "packed_True.mcap")
    assert summary is not None and summary.chunk_count > 5


# -- files deleted under the recorder -----------------------------------------------------------


def test_out_dir_deleted_mid_session_continues_in_a_new_part(tmp_path: Path) -> None:
    out = tmp_path / "out"
    f = Feeder(out, Disk())
    stream = generated_stream(n=2400)
    cut = len(stream) // 3
    f.feed(stream[:cut])
    first = f.rec.current_file
    assert first is not None
    shutil.rmtree(out)  # the operator cleans the wrong directory
    f.feed(stream[cut:])
    f.rec.close()
    kinds = f.kinds()
    assert kinds[:2] == ["recorder.vanished", "recorder.recovered"], kinds
    gone = f.notices[0]
    assert gone.severity == "error" and f"{out} was deleted" in gone.message
    assert gone.data["lost"] == [str(first), str(first.with_suffix(".ubx"))]
    stats = f.rec.stats
    assert stats.lost_files == (first, first.with_suffix(".ubx"))
    assert all(p.exists() for p in (*stats.files, *stats.sidecars))  # only what exists named
    assert first not in stats.files and len(stats.files) >= 1
    # everything since the last check before the deletion, and all after it, in the new parts:
    # the stream's tail, byte for byte, from at most one flush interval before the cut
    got = raw_of(list(stats.files))
    assert stream.endswith(got) and len(got) >= len(stream) - cut
    assert b"".join(p.read_bytes() for p in stats.sidecars) == got
    meta = read_metadata(stats.files[0])["groundstation"]
    assert meta["part"] == "2" and meta["session_id"] == f.rec.session_id
    assert "was deleted" in meta["after_write_failure"]
    assert stats.write_failures == 0 and stats.dropped_raw_bytes == 0
    # the one reader reads the new part (and its later ones) as the session's tail
    assert b"".join(d for d, _ in Recording(stats.files[0]).chunks()) == got


def test_out_dir_deleted_with_rotation_on_loses_nothing_after_it(tmp_path: Path) -> None:
    out = tmp_path / "out"
    clock = FakeClock()
    rec = SessionRecorder(out, "st1", chunk_size_bytes=512, clock=clock,
                          flush_interval_ns=50_000_000, rotate_size_bytes=6_000)
    rec.open()
    stream = generated_stream(n=2400)
    cut = len(stream) // 2
    notices: list[Event] = []
    for i in range(0, len(stream), 97):
        if i <= cut < i + 97:
            shutil.rmtree(out)
        rec.write_raw(stream[i : i + 97], clock())
        rec.maybe_flush()
        notices += rec.take_notices()
    rec.close()
    notices += rec.take_notices()
    assert "recorder.write_failed" not in [e.kind for e in notices]  # never "cannot write None"
    vanished = [e for e in notices if e.kind == "recorder.vanished"]
    assert len(vanished) == 1 and len(vanished[0].data["lost"]) >= 4  # parts rotated before
    stats = rec.stats
    assert len(stats.files) >= 2 and all(p.exists() for p in stats.files)
    got = raw_of(list(stats.files))
    assert stream.endswith(got) and len(got) >= len(stream) - cut
    assert b"".join(d for d, _ in Recording(stats.files[0]).chunks()) == got


def test_out_dir_deleted_while_a_rotation_closes_its_part_is_alerted(tmp_path: Path) -> None:
    """The directory removed after the check before a rotation and before the closed part's
    summary is written: the rotation makes the directory again for the next part, and the
    lost parts are alerted at once, not only in the session's end summary (a full suite run
    saw the daemon rotate on without the alert)."""
    out = tmp_path / "out"
    clock = FakeClock()
    rec = SessionRecorder(out, "st1", chunk_size_bytes=512, clock=clock,
                          flush_interval_ns=10**12, rotate_size_bytes=6_000)
    rec.open()
    close_file = rec._close_file
    removed: list[Path] = []

    def close_after_removal() -> None:
        if not removed:  # the first rotation: the operator's rmtree wins the race
            removed.extend(sorted(out.iterdir()))
            shutil.rmtree(out)
        close_file()

    rec._close_file = close_after_removal  # type: ignore[method-assign]
    stream = generated_stream(n=2400)
    notices: list[Event] = []
    for i in range(0, len(stream), 97):
        rec.write_raw(stream[i : i + 97], clock())
        notices += rec.take_notices()
        if removed:
            break
    vanished = [e for e in notices if e.kind == "recorder.vanished"]
    assert removed and len(vanished) == 1, [e.kind for e in notices]
    assert set(vanished[0].data["lost"]) == {str(p) for p in removed}
    assert "was deleted or moved" in vanished[0].message
    rec.close()
    assert set(rec.stats.lost_files) == set(removed)
    assert all(p.exists() for p in rec.stats.files)


def test_a_deleted_sidecar_is_cut_from_its_mcap_without_duplicates(tmp_path: Path) -> None:
    f = Feeder(tmp_path, Disk())
    stream = generated_stream(n=1200)
    f.feed(stream[:20_000])
    side = f.rec.stats.sidecars[0]
    side.unlink()
    f.feed(stream[20_000:])
    f.rec.close()
    stats = f.rec.stats
    assert stats.lost_files == (side,) and len(stats.files) == 2  # the first MCAP is kept
    assert f.kinds()[:2] == ["recorder.vanished", "recorder.recovered"]
    assert raw_of(list(stats.files)) == stream  # every byte once: the MCAP was cut back
    assert stats.sidecars[0].read_bytes() == raw_of([stats.files[1]])


def test_a_directory_that_cannot_be_made_again_holds_the_data_and_retries(
    tmp_path: Path,
) -> None:
    out = tmp_path / "out"
    f = Feeder(out, Disk())
    stream = generated_stream(n=2400)
    cut = len(stream) // 3
    f.feed(stream[:cut])
    shutil.rmtree(out)
    out.write_bytes(b"")  # a file where the directory was: mkdir fails
    f.feed(stream[cut : 2 * cut])
    assert f.kinds() == ["recorder.vanished", "recorder.write_failed"]
    assert f"cannot make {out} again" in f.notices[0].message
    assert f.rec.failing and f.rec.stats.held_bytes > 0
    f.idle(1.0)
    assert f.rec.failing  # still a file
    out.unlink()
    f.idle(1.0)
    assert f.kinds() == ["recorder.vanished", "recorder.write_failed", "recorder.recovered"]
    f.feed(stream[2 * cut :])
    f.rec.close()
    stats = f.rec.stats
    got = raw_of(list(stats.files))
    assert stream.endswith(got) and len(got) >= len(stream) - cut
    assert stats.write_failures == 1 and stats.dropped_raw_bytes == 0
