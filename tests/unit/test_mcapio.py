"""The MCAP writer's own message and chunk path (``storage/mcapio._MessageAppender``: messages,
chunk records, message indexes, chunk indexes) writes the same file, byte for byte, as the
``mcap`` library's ``add_message`` and chunk finalisation, for every compression."""

from __future__ import annotations

import errno
import os
import random
from pathlib import Path

import pytest

from groundstation.storage.mcapio import (
    ChannelSpec,
    ExactFile,
    McapFileWriter,
    iter_messages,
    json_channel,
)


def _write(path: Path, library_path: bool, chunk_size: int, compression: str = "zstd",
           background: bool = False) -> int:
    rng = random.Random(7)
    raw = ChannelSpec("/ubx/raw", "ubx")
    js = json_channel("/gnss/epoch", {"title": "RawEpoch", "type": "object"})
    late = json_channel("/events", {"title": "Event", "type": "object"})
    w = McapFileWriter(path, chunk_size_bytes=chunk_size, compression=compression,
                       background=background)
    if library_path:
        w._appender = None  # the library's add_message, as when its internals change
    else:
        assert w._appender is not None  # the fast path is in use with this mcap version
    t = 1_700_000_000_000_000_000
    for i in range(3000):
        t += rng.randrange(-5_000_000, 20_000_000)  # log times out of order now and then
        spec = raw if rng.random() < 0.5 else js
        if i > 1500 and rng.random() < 0.1:
            spec = late  # a channel registered in the middle of a chunk
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 300)))
        w.add(spec, data, t, t + rng.randrange(10**9))
        if i % 700 == 0:
            w.flush()  # chunks closed by flushes as well as by size
    w.finish()
    return w.messages


def test_own_message_path_writes_the_librarys_bytes(tmp_path: Path) -> None:
    for compression in ("zstd", "lz4", "none"):
        for chunk_size in (1024, 64 * 1024):
            name = f"{compression}{chunk_size}.mcap"
            fast, lib = tmp_path / f"fast-{name}", tmp_path / f"lib-{name}"
            assert (_write(fast, False, chunk_size, compression)
                    == _write(lib, True, chunk_size, compression) == 3000)
            assert fast.read_bytes() == lib.read_bytes(), name
            assert sum(1 for _ in iter_messages(fast)) == 3000
            # chunks compressed and written by the background writer: the same bytes
            threaded = tmp_path / f"bg-{name}"
            assert _write(threaded, False, chunk_size, compression, background=True) == 3000
            assert threaded.read_bytes() == lib.read_bytes(), name


class _FillingFile(ExactFile):
    """A file on a disk that fills up after ``room`` bytes (ENOSPC from then on)."""

    def __init__(self, path: Path, room: int) -> None:
        super().__init__(path)
        self.room = room

    def _write_some(self, data: memoryview) -> int:
        if self.room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.path))
        n = min(len(data), self.room)
        self.room -= n
        return super()._write_some(data[:n])


def test_background_write_failure_is_raised_and_the_file_cut_back(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    f = _FillingFile(path, room=10**9)
    w = McapFileWriter(path, chunk_size_bytes=1024, compression="zstd", file=f, background=True)
    raw = ChannelSpec("/ubx/raw", "ubx")
    rng = random.Random(3)
    for i in range(200):
        w.add(raw, rng.randbytes(200), i, i)
    w.flush()
    good = w.size_bytes
    assert good == path.stat().st_size  # after a flush, everything handed over is written
    f.room = 5000  # the disk fills in the middle of the next chunks
    with pytest.raises(OSError) as failed:
        for i in range(200, 2000):
            w.add(raw, rng.randbytes(200), i, i)
        w.flush()
    assert failed.value.errno == errno.ENOSPC
    w.abandon(good)
    assert [m.log_time_ns for m in iter_messages(path)] == list(range(200))
