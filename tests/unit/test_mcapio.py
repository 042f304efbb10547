"""The MCAP writer's own message and chunk path (``storage/mcapio._MessageAppender``: messages,
chunk records, message indexes, chunk indexes) writes the same file, byte for byte, as the
``mcap`` library's ``add_message`` and chunk finalisation, for every compression."""

from __future__ import annotations

import random
from pathlib import Path

from groundstation.storage.mcapio import (
    ChannelSpec,
    McapFileWriter,
    iter_messages,
    json_channel,
    read_summary,
)


def _write(path: Path, library_path: bool, chunk_size: int, compression: str = "zstd") -> int:
    rng = random.Random(7)
    raw = ChannelSpec("/ubx/raw", "ubx")
    js = json_channel("/gnss/epoch", {"title": "RawEpoch", "type": "object"})
    late = json_channel("/events", {"title": "Event", "type": "object"})
    # a schema larger than the small chunks: registering it makes the chunk in progress full,
    # and the library closes the chunk there
    big = json_channel("/big", {"title": "Big", "type": "object", "description": "x" * 1500})
    w = McapFileWriter(path, chunk_size_bytes=chunk_size, compression=compression)
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
        if i in (2100, 2500):
            spec = big
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


def test_unsettled_gives_back_every_message_since_the_last_settle(tmp_path: Path) -> None:
    """What a failed write may have lost (``McapFileWriter.unsettled``) is read back from the
    chunks: every message added since the last ``settle``, in order, across chunks closed by
    size, a channel registered in the middle of a chunk and records encoded in place; the same
    on the library's path."""
    from dataclasses import dataclass

    from groundstation import jsonio

    @dataclass(frozen=True)
    class Rec:
        n: int
        text: str

    raw = ChannelSpec("/ubx/raw", "ubx")
    js = json_channel("/rec", {"title": "Rec", "type": "object"})
    big = json_channel("/big", {"title": "Big", "type": "object", "description": "x" * 1500})
    for library_path in (False, True):
        w = McapFileWriter(tmp_path / f"u{library_path}.mcap", chunk_size_bytes=1024,
                           keep_unsettled=True)
        if library_path:
            w._appender = None
        expected: list[tuple[ChannelSpec, bytes, int, int]] = []
        for i in range(120):
            if i == 40:
                w.flush()
                w.settle()
                expected.clear()
            if i % 3 == 0:
                msg = (raw, bytes([i]) * (i % 50), i, i + 1)
                w.add(*msg)
            else:
                spec = big if i in (70, 71) else js
                record = Rec(i, "é" * (i % 7))
                msg = (spec, jsonio.dumps_typed(record), i, i + 2)
                w.add_typed(spec, record, i, i + 2)
            expected.append(msg)
        assert w.unsettled() == expected
        assert len(expected) == 80
        w.finish()
        assert [m.data for m in iter_messages(tmp_path / f"u{library_path}.mcap")][40:] == [
            m[1] for m in expected]


def test_a_writer_keeps_nothing_unless_asked(tmp_path: Path) -> None:
    """Without ``keep_unsettled`` (a writer nobody settles) no closed chunk is kept."""
    raw = ChannelSpec("/ubx/raw", "ubx")
    w = McapFileWriter(tmp_path / "a.mcap", chunk_size_bytes=1024)
    assert w._appender is not None
    for i in range(100):
        w.add(raw, bytes(100), i, i)
    assert w._appender.kept == [] and w._loose == []
    for i in range(1000):  # an equal spec made anew for every message: one channel, bounded
        w.add(ChannelSpec("/ubx/raw", "ubx"), bytes(10), i, i)
    assert len(w._specs_seen) <= 256
    w.finish()
    assert {m.topic for m in iter_messages(tmp_path / "a.mcap")} == {"/ubx/raw"}
    summary = read_summary(tmp_path / "a.mcap")
    assert summary is not None and summary.messages_by_topic == {"/ubx/raw": 1100}
