"""The MCAP recorder and reader: byte-exact raw channel, schemas, naming, rotation, torn files."""

from __future__ import annotations

import asyncio
import gzip
import json
import random
from pathlib import Path

import pytest
from mcap.reader import make_reader
from streams import rxm_raw

from groundstation import gpstime
from groundstation.config import FileSourceSettings, RecorderSettings, Settings, ZenohSettings
from groundstation.live.daemon import run_daemon
from groundstation.records import Event, TimeMark
from groundstation.storage import iter_messages, iter_raw_chunks, read_metadata, read_summary
from groundstation.storage.mcapio import ReadReport
from groundstation.storage.session import SessionRecorder
from groundstation.ubx import layouts as L
from groundstation.ubx.build import build_frame
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer

T0_NS = 1_700_000_000_000_000_000


def tim_tm2(count: int, tow_ms: int) -> bytes:
    flags = L.TIM_TM2_FLAGS.compose(
        mode=1, run=1, newFallingEdge=1, newRisingEdge=1, timeBase=1, time=1
    )
    return L.TIM_TM2.frame(
        flags=flags, count=count, wnR=2300, wnF=2300, towMsR=tow_ms + 14, towSubMsR=160_000,
        towMsF=tow_ms, towSubMsF=255_555, accEst=20,
    )


def generated_stream(seed: int = 7, n: int = 240) -> bytes:
    """UBX frames (time marks, pass-through messages), garbage and cut frames, mixed."""
    rng = random.Random(seed)
    out = bytearray()
    for i in range(n):
        kind = i % 4
        if kind == 0:
            out += tim_tm2(i // 4, 100_000 + 250 * i)
        elif kind == 1:
            out += build_frame(0x0A, 0x04, rng.randbytes(rng.randint(0, 120)))  # MON-VER
        elif kind == 2:
            out += rng.randbytes(rng.randint(1, 40)).replace(b"\xb5", b"\x00")
        else:
            frame = build_frame(0x01, 0x22, rng.randbytes(20))
            out += frame[: rng.randint(1, len(frame) - 1)]  # cut by a dropout
    return bytes(out)


class FakeClock:
    def __init__(self, start_ns: int = T0_NS) -> None:
        self.now = start_ns

    def __call__(self) -> int:
        self.now += 1_000_000  # 1 ms per call
        return self.now


def record_stream(tmp_path: Path, data: bytes, chunk: int = 97, **kw: object) -> SessionRecorder:
    clock = FakeClock()
    rec = SessionRecorder(tmp_path, "st1", receiver="LEA-6T", configuration={"a": 1},
                          chunk_size_bytes=512, clock=clock, **kw)  # type: ignore[arg-type]
    rec.open()
    dec = Decoder()
    framer = UbxFramer()
    for i in range(0, len(data), chunk):
        piece = data[i : i + chunk]
        t = clock()
        rec.write_raw(piece, t)
        for frame in framer.feed(piece, t):
            rec.write_record(dec.decode(frame), t)
        if i % (chunk * 5) == 0:
            rec.flush()
    for frame in framer.flush(clock()):  # frames still waiting for a claimed length
        rec.write_record(dec.decode(frame), frame.t_host_ns)
    rec.write_record(Event("source.outage", clock(), "gone", "warning", {"duration_s": 1.5}), 0)
    return rec


def test_raw_channel_and_sidecar_are_byte_exact(tmp_path: Path) -> None:
    data = generated_stream()
    rec = record_stream(tmp_path, data)
    rec.close()
    (mcap_path,), (ubx_path,) = rec.stats.files, rec.stats.sidecars
    assert mcap_path.name == "st1_20231114T221320Z.mcap"
    assert ubx_path.read_bytes() == data
    assert b"".join(d for d, _ in iter_raw_chunks(mcap_path)) == data
    summary = read_summary(mcap_path)
    assert summary is not None and summary.chunk_count > 3
    assert summary.messages_by_topic["/ubx/raw"] == len(range(0, len(data), 97))
    meta = read_metadata(mcap_path)
    assert meta["groundstation"]["station"] == "st1"
    assert meta["groundstation"]["receiver"] == "LEA-6T"
    assert json.loads(meta["configuration"]["json"]) == {"a": 1}
    assert "software_version" in meta["groundstation"]


def test_json_channels_have_schemas_and_gps_publish_time(tmp_path: Path) -> None:
    rec = record_stream(tmp_path, generated_stream())
    rec.close()
    path = rec.stats.files[0]
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        topics = {ch.topic: ch for ch in summary.channels.values()}
        assert topics["/ubx/raw"].message_encoding == "ubx" and topics["/ubx/raw"].schema_id == 0
        tm = topics["/gnss/timemark"]
        assert tm.message_encoding == "json"
        schema = summary.schemas[tm.schema_id]
        assert schema.encoding == "jsonschema" and schema.name == "TimeMark"
        assert "falling_t_gps_ns" in json.loads(schema.data)["properties"]
    marks = list(iter_messages(path, topics=["/gnss/timemark"]))
    assert len(marks) == 60
    body = json.loads(marks[0].data)
    assert body["type"] == "TimeMark" and body["count"] == 0
    expected = gpstime.gps_to_unix_ns(gpstime.gps_ns_from_ms(2300, 100_000, 255_555))
    assert marks[0].publish_time_ns == expected
    events = [json.loads(m.data) for m in iter_messages(path, topics=["/groundstation/event"])]
    assert events[-1]["kind"] == "source.outage"


def test_never_overwrites(tmp_path: Path) -> None:
    first = record_stream(tmp_path, b"abc")
    first.close()
    second = record_stream(tmp_path, b"def")  # same clock: same second, same stem
    second.close()
    assert first.stats.files[0].name == "st1_20231114T221320Z.mcap"
    assert second.stats.files[0].name == "st1_20231114T221320Z_1.mcap"
    assert second.stats.sidecars[0].read_bytes() == b"def"
    assert first.stats.sidecars[0].read_bytes() == b"abc"


def test_rotation_by_size_keeps_every_byte(tmp_path: Path) -> None:
    data = generated_stream(n=2000)
    rec = record_stream(tmp_path, data, rotate_size_bytes=8_000)
    rec.close()
    files = rec.stats.files
    assert len(files) >= 3 and len(set(files)) == len(files)
    raw = b"".join(d for f in files for d, _ in iter_raw_chunks(f))
    assert raw == data
    assert b"".join(p.read_bytes() for p in rec.stats.sidecars) == data
    metas = [read_metadata(f)["groundstation"] for f in files]
    assert {m["session_id"] for m in metas} == {rec.session_id}
    assert [m["part"] for m in metas] == [str(i + 1) for i in range(len(files))]
    assert all(read_summary(f) is not None for f in files)


def test_unfinished_file_reads_up_to_last_complete_chunk(tmp_path: Path) -> None:
    data = generated_stream(n=800)
    rec = record_stream(tmp_path, data)
    rec.flush()
    path = rec.stats.files[0]
    torn = path.read_bytes()  # the writer was never finished: no summary, no footer
    rec.close()
    full = path.read_bytes()
    (tmp_path / "torn.mcap").write_bytes(torn)
    report = ReadReport()
    raw = b"".join(m.data for m in iter_messages(tmp_path / "torn.mcap", ["/ubx/raw"], report))
    assert raw == data and not report.finished
    assert read_summary(tmp_path / "torn.mcap") is None
    # Cut anywhere: never raises, returns a prefix that only grows with the cut.
    previous = -1
    for cut in range(len(torn) // 2, len(full), 1013):
        p = tmp_path / f"cut{cut}.mcap"
        p.write_bytes(full[:cut])
        got = b"".join(d for d, _ in iter_raw_chunks(p))
        assert data.startswith(got)
        assert len(got) >= previous
        previous = len(got)
        p.unlink()


def test_pipeline_from_gz_file_in_process(tmp_path: Path) -> None:
    data = generated_stream(n=400)
    src = tmp_path / "in.ubx.gz"
    src.write_bytes(gzip.compress(data))
    settings = Settings(
        source=FileSourceSettings(path=src, read_size_bytes=333), station="gz",
        recorder=RecorderSettings(out_dir=tmp_path / "out"),
        zenoh=ZenohSettings(enabled=False),  # (the default endpoint is not this test's)
    )
    files: list[Path] = []
    summary = asyncio.run(run_daemon(settings, on_file=files.append))
    assert summary.stopped_by == "end of source"
    assert summary.files == tuple(files) and len(files) == 1
    assert summary.bytes_in == len(data)
    assert b"".join(d for d, _ in iter_raw_chunks(files[0])) == data
    assert summary.sidecars[0].read_bytes() == data
    marks = [json.loads(m.data) for m in iter_messages(files[0], ["/gnss/timemark"])]
    assert [m["count"] for m in marks] == list(range(100))
    assert read_summary(files[0]) is not None
    assert TimeMark.__name__ == marks[0]["type"]


def test_missing_file_source_is_an_error(tmp_path: Path) -> None:
    from groundstation.errors import InputError

    settings = Settings(source=FileSourceSettings(path=tmp_path / "nope.ubx"),
                        recorder=RecorderSettings(out_dir=tmp_path / "out"),
                        zenoh=ZenohSettings(enabled=False))
    with pytest.raises(InputError):
        asyncio.run(run_daemon(settings))
    # refused before any file is created (FileSource.claim)
    assert not list((tmp_path / "out").glob("*.mcap"))


def test_sink_bursts_write_and_announce_as_item_by_item(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """The recorder sink hands each burst to the session (``write_items``); the files, and
    where each new part is announced (the clock's reading then), are those of writing the same
    items one by one (``RecorderSink.write``), with rotations by size and by duration falling
    inside bursts."""
    import secrets

    from groundstation.live.recorder_sink import RecorderSink
    from groundstation.records import RawChunk

    monkeypatch.setattr(secrets, "token_hex", lambda n: "ab" * n)  # one session id
    data = generated_stream(n=1200)
    items: list[object] = []
    dec, framer = Decoder(), UbxFramer()
    for k, i in enumerate(range(0, len(data), 97)):
        t = T0_NS + i * 86_806
        items.append(RawChunk(data[i : i + 97], t))
        items += [dec.decode(f) for f in framer.feed(data[i : i + 97], t)]
        if k % 7 == 0:
            items.append(Event("test.kind", 0, "no host time", "info", {"k": k}))  # sink clock
    for kw in ({"rotate_size_bytes": 3000}, {"rotate_duration_ns": 40_000_000}):
        seen: list[list[tuple[str, int]]] = []
        contents: list[list[bytes]] = []
        for burst in (False, True):
            out = tmp_path / f"{burst}{len(seen)}{sorted(kw)[0]}"
            clock = FakeClock()
            rec = SessionRecorder(out, "st1", chunk_size_bytes=512, clock=clock,
                                  **kw)  # type: ignore[arg-type]
            announced: list[tuple[str, int]] = []

            def announce(path: Path, announced: list[tuple[str, int]] = announced,
                         clock: FakeClock = clock) -> None:
                announced.append((path.name, clock.now))

            sink = RecorderSink(rec, 0.5, announce, clock=clock)
            sink.open()
            for j in range(0, len(items), 40):
                part = items[j : j + 40]
                if burst:
                    sink._write_burst(part)  # type: ignore[arg-type]
                else:
                    for item in part:
                        sink.write(item)  # type: ignore[arg-type]
                rec.maybe_flush()
            rec.close()
            seen.append(announced)
            contents.append([p.read_bytes() for p in sorted(out.iterdir())])
        assert seen[0] == seen[1] and len(seen[0]) > 3, kw
        assert contents[0] == contents[1], kw


def test_one_location_fix_per_epoch_when_the_receiver_sends_two_solutions(tmp_path: Path) -> None:
    """The LEA-6T sends NAV-SOL and NAV-POSLLH every epoch: the map gets one point per epoch
    (the first solution with a position), not two of the same instant and place."""
    sol_flags = L.NAV_SOL_FLAGS.compose(gpsfixOK=1, wknSet=1, towSet=1)
    data = bytearray()
    for k in range(6):
        itow = 100_000 + 200 * k
        data += rxm_raw(2300, itow, [(3, 0), (7, 0)])  # its week dates NAV-POSLLH's TOW
        if k != 3:  # one epoch with NAV-POSLLH alone
            data += L.NAV_SOL.frame(  # fTOW: its time is not NAV-POSLLH's to the ns
                iTOW=itow, fTOW=-123_456 * (k % 2), week=2300, gpsFix=3, flags=sol_flags,
                ecefX=377469655,
                ecefY=-59664791, ecefZ=508948565, pAcc=250, numSV=8)
        data += L.NAV_POSLLH.frame(iTOW=itow, lon=-89900000, lat=533400000, height=50_000,
                                   hMSL=0, hAcc=200, vAcc=300)
    rec = record_stream(tmp_path, bytes(data))
    rec.close()
    fixes = [m for m in iter_messages(rec.stats.files[0])
             if m.topic == "/groundstation/location"]
    navs = [m for m in iter_messages(rec.stats.files[0]) if m.topic == "/gnss/nav"]
    assert len(navs) == 11
    stamps = [json.loads(m.data)["timestamp"] for m in fixes]
    assert len(fixes) == 6 and len({(s["sec"], s["nsec"]) for s in stamps}) == 6
    # the epoch without NAV-SOL still gets its point, from NAV-POSLLH (accuracy h / v)
    assert json.loads(fixes[3].data)["position_covariance"][8] == pytest.approx(0.09)
