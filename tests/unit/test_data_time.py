"""The data's own clock (live/data_time.py): a `.ubx` stream timed from the epochs the pipeline
decoded, and the one framing pass of `run --file X.ubx` (the file source no longer frames it
itself); an epoch the decoder found implausible does not move it."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from streams import TOW0_MS, WEEK, rxm_raw, t_gps_ns

from groundstation.config import FileSourceSettings, load_settings
from groundstation.gpstime import gps_to_unix_ns
from groundstation.live.daemon import Pipeline
from groundstation.live.data_time import DATA_TIME_WAIT_BYTES, UNTIMED, DataClock
from groundstation.live.sources import FileSource
from groundstation.pacing import link_time_ns
from groundstation.records import Frame, Item, RawChunk, RawEpoch, UndecodedFrame
from groundstation.ubx import framer as framer_module
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer

SATS = [(3, 0), (7, 0)]


def utc(tow_ms: int) -> int:
    return gps_to_unix_ns(t_gps_ns(WEEK, tow_ms))


class Decoded:
    """The pipeline's first steps: frame and decode, records out (an undecoded frame left out)."""

    def __init__(self) -> None:
        self.framer, self.decoder = UbxFramer(), Decoder()

    def __call__(self, data: bytes) -> list[Item]:
        out: list[Item] = []
        for f in self.framer.feed(data, UNTIMED):
            rec = self.decoder.decode(f)
            if not isinstance(rec, (Frame, UndecodedFrame)):
                out.append(rec)
        return out


def test_chunks_before_the_first_epoch_take_its_time_and_time_never_goes_back() -> None:
    decoded, clock = Decoded(), DataClock(1_000, 11_520)
    head = b"\x00" * 100
    assert clock.stamp(head, decoded(head)) == []  # held
    e1 = rxm_raw(WEEK, TOW0_MS + 1000, SATS)
    out = clock.stamp(e1, decoded(e1))
    assert [(c, t) for c, _, t in out] == [(head, utc(TOW0_MS + 1000)), (e1, utc(TOW0_MS + 1000))]
    (rec,) = out[1][1]
    assert isinstance(rec, RawEpoch) and rec.t_host_ns == utc(TOW0_MS + 1000)  # restamped
    older = rxm_raw(WEEK, TOW0_MS + 800, SATS)  # an epoch out of order does not move time back
    ((_, items, t),) = clock.stamp(older, decoded(older))
    assert t == utc(TOW0_MS + 1000) and isinstance(items[0], RawEpoch)
    assert items[0].t_host_ns == t
    assert clock.now_ns() == utc(TOW0_MS + 1000)


def test_an_epoch_the_decoder_refused_does_not_move_the_data_clock() -> None:
    decoded, clock = Decoded(), DataClock(1_000, 11_520)
    e1 = rxm_raw(WEEK, TOW0_MS, SATS)
    assert [t for _, _, t in clock.stamp(e1, decoded(e1))] == [utc(TOW0_MS)]
    ahead = rxm_raw(WEEK + 1, TOW0_MS + 200, SATS)  # a week ahead: implausible
    assert [t for _, _, t in clock.stamp(ahead, decoded(ahead))] == [utc(TOW0_MS)]
    e2 = rxm_raw(WEEK, TOW0_MS + 200, SATS)
    assert [t for _, _, t in clock.stamp(e2, decoded(e2))] == [utc(TOW0_MS + 200)]


def test_a_stream_without_epochs_is_timed_as_a_link_would_deliver_it() -> None:
    clock = DataClock(5_000, 1_000.0)
    block = b"\x01" * (DATA_TIME_WAIT_BYTES // 2)
    assert clock.stamp(block, []) == []
    assert clock.stamp(block, []) == []  # exactly the limit: still held
    out = clock.stamp(b"\x02" * 10, [])
    assert [t for _, _, t in out] == [
        link_time_ns(5_000, 0, 1_000.0), link_time_ns(5_000, len(block), 1_000.0),
        link_time_ns(5_000, 2 * len(block), 1_000.0)]
    # once timed by the link, a later epoch does not change the rule
    late = rxm_raw(WEEK, TOW0_MS, SATS)
    ((_, _, t),) = clock.stamp(late, Decoded()(late))
    assert t == link_time_ns(5_000, 2 * len(block) + 10, 1_000.0)


def test_a_stream_ending_before_its_first_epoch_is_flushed_with_link_times() -> None:
    clock = DataClock(7_000, 100.0)
    assert clock.stamp(b"abc", []) == [] and clock.stamp(b"de", []) == []
    assert [(c, t) for c, _, t in clock.flush()] == [(b"abc", 7_000), (b"de", 7_000 + 30_000_000)]
    assert clock.flush() == []


def test_run_file_ubx_frames_each_byte_once_and_times_chunks_by_their_epochs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    epochs = [rxm_raw(WEEK, TOW0_MS + 200 * k, SATS) for k in range(50)]
    path = tmp_path / "f.ubx"
    path.write_bytes(b"".join(epochs))
    settings = load_settings(None, environ={}, overrides={
        "source": {"path": path, "read_size_bytes": 300}, "zenoh": {"enabled": False},
        "monitor": {"enabled": False}})
    assert isinstance(settings.source, FileSourceSettings)
    scans = [0]
    real_scan = framer_module.scan_ubx

    def counting_scan(*args: object, **kwargs: object) -> object:
        scans[0] += 1
        return real_scan(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(framer_module, "scan_ubx", counting_scan)
    chunks: list[RawChunk] = []
    pipeline = Pipeline(settings, source=FileSource(settings.source), record=False)
    real_publish = pipeline.fanout.publish

    def spy(item: object, origin: str | None = None) -> None:
        if type(item) is RawChunk:
            chunks.append(item)
        real_publish(item, origin)  # type: ignore[arg-type]

    pipeline.fanout.publish = spy  # type: ignore[method-assign]
    summary = asyncio.run(pipeline.run())
    assert summary.frames == 50 and b"".join(c.data for c in chunks) == path.read_bytes()
    # one framing pass: one scan per chunk read (plus the final flush), not two
    assert scans[0] <= len(chunks) + 1
    # each chunk carries the time of the latest epoch it completed
    size = len(epochs[0])
    done = 0
    last = None
    for c in chunks:
        done += len(c.data)
        completed = done // size
        if completed:
            last = utc(TOW0_MS + 200 * (completed - 1))
        assert c.t_host_ns == last
