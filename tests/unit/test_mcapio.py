"""The MCAP writer's own message path (``storage/mcapio._MessageAppender``) writes the same file,
byte for byte, as the ``mcap`` library's ``add_message``."""

from __future__ import annotations

import random
from pathlib import Path

from groundstation.storage.mcapio import ChannelSpec, McapFileWriter, iter_messages, json_channel


def _write(path: Path, library_path: bool, chunk_size: int) -> int:
    rng = random.Random(7)
    raw = ChannelSpec("/ubx/raw", "ubx")
    js = json_channel("/gnss/epoch", {"title": "RawEpoch", "type": "object"})
    w = McapFileWriter(path, chunk_size_bytes=chunk_size, compression="zstd")
    if library_path:
        w._appender = None  # the library's add_message, as when its internals change
    else:
        assert w._appender is not None  # the fast path is in use with this mcap version
    t = 1_700_000_000_000_000_000
    for i in range(3000):
        t += rng.randrange(-5_000_000, 20_000_000)  # log times out of order now and then
        spec = raw if rng.random() < 0.5 else js
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 300)))
        w.add(spec, data, t, t + rng.randrange(10**9))
        if i % 700 == 0:
            w.flush()  # chunks closed by flushes as well as by size
    w.finish()
    return w.messages


def test_own_message_path_writes_the_librarys_bytes(tmp_path: Path) -> None:
    for chunk_size in (1024, 64 * 1024):
        fast, lib = tmp_path / f"fast{chunk_size}.mcap", tmp_path / f"lib{chunk_size}.mcap"
        assert _write(fast, False, chunk_size) == _write(lib, True, chunk_size) == 3000
        assert fast.read_bytes() == lib.read_bytes()
        assert sum(1 for _ in iter_messages(fast)) == 3000
