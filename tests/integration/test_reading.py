"""The one recording reader: format by content, unfinished files, a session's parts followed."""

from __future__ import annotations

import gzip
import logging
import shutil
from pathlib import Path

import pytest
from test_recorder import FakeClock, generated_stream
from test_recorder_faults import Disk, Feeder

from groundstation.errors import InputError
from groundstation.offline.inspect import inspect_path
from groundstation.pacing import Pacer, link_time_ns
from groundstation.storage import iter_raw_chunks
from groundstation.storage.naming import session_start_ns
from groundstation.storage.reading import Recording, detect_format, iter_chunks, session_parts
from groundstation.storage.session import SessionRecorder

JPEG = bytes.fromhex("ffd8ffe000104a46494600010101004800480000ffdb0043") + bytes(range(256)) * 8


def record(out: Path, data: bytes, *, station: str = "st1", piece: int = 97,
           clock: FakeClock | None = None, **kw: object) -> SessionRecorder:
    """``data`` recorded as a live session (raw chunks only), in ``piece``-byte chunks."""
    rec = SessionRecorder(out, station, chunk_size_bytes=512, clock=clock or FakeClock(),
                          **kw)  # type: ignore[arg-type]
    rec.open()
    for i in range(0, len(data), piece):
        rec.write_raw(data[i : i + piece], 1_000 + i)
        rec.maybe_flush()
    rec.close()
    return rec


def raw(path: Path, **kw: bool) -> bytes:
    return b"".join(c for c, _ in iter_chunks(path, **kw))


def test_format_comes_from_content_not_the_name(tmp_path: Path) -> None:
    data = generated_stream(n=200)
    rec = record(tmp_path / "rec", data)
    (mcap,), (side,) = rec.stats.files, rec.stats.sidecars
    lying = {
        "really_mcap.ubx": (mcap.read_bytes(), "mcap"),
        "really_gzip.mcap": (gzip.compress(data), "gzip"),
        "really_raw.ubx.gz": (data, "raw"),
    }
    for name, (content, fmt) in lying.items():
        p = tmp_path / name
        p.write_bytes(content)
        assert detect_format(p) == fmt, name
        assert raw(p) == data, name
    # recorded chunk times come with an MCAP only
    times = [t for _, t in iter_chunks(tmp_path / "really_mcap.ubx")]
    assert times == [1_000 + i for i in range(0, len(data), 97)]
    assert {t for _, t in iter_chunks(side)} == {0}


def test_unfinished_mcap_reads_up_to_its_last_complete_chunk(tmp_path: Path) -> None:
    data = generated_stream(n=600)
    (mcap,) = record(tmp_path / "rec", data).stats.files
    full = mcap.read_bytes()
    previous = 0
    for cut in (len(full) // 3, len(full) // 2, len(full) * 2 // 3):
        torn = tmp_path / f"torn{cut}.mcap"
        torn.write_bytes(full[:cut])
        got = raw(torn)
        assert data.startswith(got)
        assert previous < len(got) < len(data)
        previous = len(got)
        assert inspect_path(torn).frames > 0
    footless = tmp_path / "footless.mcap"  # killed while writing its summary
    footless.write_bytes(full[:-200])
    assert raw(footless) == data


def test_torn_gzip_reads_what_it_holds(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    data = generated_stream(n=2000)
    whole = gzip.compress(data)
    p = tmp_path / "cut.ubx.gz"
    p.write_bytes(whole[: len(whole) * 2 // 3])
    with caplog.at_level(logging.WARNING):
        got = raw(p)
    assert got and data.startswith(got) and len(got) < len(data)
    assert "ends early" in caplog.text


@pytest.mark.parametrize("content", [b"", JPEG, b"\x89MCAP", b"\x1f\x8b"])
def test_no_ubx_in_the_file_does_not_crash(tmp_path: Path, content: bytes) -> None:
    p = tmp_path / "photo.ubx"
    p.write_bytes(content)
    got = raw(p)
    assert got == (b"" if content.startswith(b"\x1f\x8b") else content)
    assert inspect_path(p).frames == 0


def test_missing_path_and_directory_are_input_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        Recording(tmp_path / "nope.mcap")
    with pytest.raises(InputError, match="directory"):
        Recording(tmp_path)


def rotated(tmp_path: Path, data: bytes, clock: FakeClock | None = None) -> SessionRecorder:
    """A session split in many parts, every part opened in the same second (names ``_1`` ...
    ``_11``: name order is not part order)."""
    rec = record(tmp_path, data, clock=clock, rotate_size_bytes=1500)
    assert len(rec.stats.files) >= 11
    return rec


def test_a_session_split_in_parts_reads_as_one(tmp_path: Path) -> None:
    data = generated_stream(n=1500)
    rec = rotated(tmp_path / "s", data)
    files, sides = list(rec.stats.files), list(rec.stats.sidecars)
    assert sorted(files) != files  # "_10" sorts before "_2": the order is the part number
    first = files[0]
    assert session_parts(first) == tuple(files)
    assert raw(first) == data
    assert [t for _, t in iter_chunks(first)] == [1_000 + i for i in range(0, len(data), 97)]
    assert raw(sides[0]) == data  # the sidecars follow the same parts
    assert session_parts(sides[0]) == tuple(sides)
    # a later part reads the session from there on
    k = 4
    tail = b"".join(d for f in files[k:] for d, _ in iter_raw_chunks(f))
    assert raw(files[k]) == tail and data.endswith(tail)
    assert raw(sides[k]) == tail
    # only the given file
    assert raw(first, follow_parts=False) == b"".join(d for d, _ in iter_raw_chunks(first))
    # progress covers every part
    r = Recording(first)
    assert r.size_bytes == sum(f.stat().st_size for f in files)
    for _ in r.chunks():
        pass
    assert r.progress == 1.0


def test_other_sessions_and_files_beside_it_are_not_read(tmp_path: Path) -> None:
    out = tmp_path / "s"
    a = generated_stream(seed=1, n=800)
    b = generated_stream(seed=2, n=800)
    first = rotated(out, a).stats.files[0]
    # the same station's next session, one second later, also in parts
    later = rotated(out, b, clock=FakeClock(start_ns=FakeClock().now + 1_000_000_000))
    assert later.session_id != Path(first).stem
    # another program's MCAP and a torn copy of a part with a station-like name
    shutil.copy(first, out / "st1_other.mcap.bak")
    (out / "st1_99999999T999999Z.mcap").write_bytes(b"\x89MCAP0\r\n")
    assert raw(first) == a
    assert raw(later.stats.files[0]) == b


def test_two_daemons_of_one_station_in_one_second_get_distinct_sessions(
    tmp_path: Path,
) -> None:
    """Two daemons named alike, started in the same second, rotating into one directory, their
    parts interleaved by name: distinct session ids keep each session's parts its own (with
    one id the reader would follow one session into the other)."""
    a_data = generated_stream(seed=1, n=1200)
    b_data = generated_stream(seed=2, n=1200)
    a = SessionRecorder(tmp_path, "st1", chunk_size_bytes=512, clock=FakeClock(),
                        rotate_size_bytes=1500)
    b = SessionRecorder(tmp_path, "st1", chunk_size_bytes=512, clock=FakeClock(),
                        rotate_size_bytes=1500)
    a.open()
    b.open()
    assert a.session_id != b.session_id
    assert a.session_id.startswith("st1_20231114T221320Z-")
    assert session_start_ns(a.session_id) == session_start_ns(b.session_id) == (
        session_start_ns(a.stats.files[0].stem))
    for i in range(0, max(len(a_data), len(b_data)), 97):
        for rec, data in ((a, a_data), (b, b_data)):
            if data[i : i + 97]:
                rec.write_raw(data[i : i + 97], 1_000 + i)
                rec.maybe_flush()
    a.close()
    b.close()
    assert len(a.stats.files) >= 5 and len(b.stats.files) >= 5
    assert raw(a.stats.files[0]) == a_data and raw(b.stats.files[0]) == b_data
    assert raw(a.stats.sidecars[0]) == a_data and raw(b.stats.sidecars[0]) == b_data
    # a later part still reads the session's tail from there
    assert a_data.endswith(raw(a.stats.files[3]))


def test_a_missing_part_is_reported_and_skipped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = generated_stream(n=1500)
    rec = rotated(tmp_path, data)
    files, sides = list(rec.stats.files), list(rec.stats.sidecars)
    want = b"".join(d for f in files[:2] + files[3:] for d, _ in iter_raw_chunks(f))
    want_side = b"".join(s.read_bytes() for i, s in enumerate(sides) if i not in (2, 5))
    files[2].unlink()  # its sidecar stays, but the parts are known through the MCAPs
    sides[5].unlink()
    with caplog.at_level(logging.WARNING):
        assert raw(files[0]) == want
        assert raw(sides[0]) == want_side
    assert "part(s) 3-3 missing" in caplog.text
    assert "sidecar of part 6" in caplog.text


def test_parts_written_after_a_full_disk_read_as_one(tmp_path: Path) -> None:
    disk = Disk()
    f = Feeder(tmp_path, disk)
    stream = generated_stream(n=2400)
    cuts = [0, len(stream) // 4, len(stream) // 2, len(stream)]
    for i, (a, b) in enumerate(zip(cuts, cuts[1:], strict=False)):
        f.feed(stream[a:b])
        if i == 0:
            disk.fill(room=100)  # fails in the middle of the second quarter ...
        elif i == 1:
            disk.full = False  # ... and the retry opens part 2
            f.idle(1.0)
    f.rec.close()
    files = f.rec.stats.files
    assert f.rec.stats.write_failures == 1 and len(files) == 2
    assert raw(files[0]) == stream  # the abandoned, unfinished first part, then the next
    assert raw(f.rec.stats.sidecars[0]) == stream


def test_gzipped_sidecars_follow_too(tmp_path: Path) -> None:
    data = generated_stream(n=1500)
    rec = rotated(tmp_path, data)
    for side in rec.stats.sidecars:
        side.with_name(side.name + ".gz").write_bytes(gzip.compress(side.read_bytes()))
        side.unlink()
    first = rec.stats.sidecars[0]
    assert raw(first.with_name(first.name + ".gz")) == data


def test_pacer_keeps_the_recorded_pace() -> None:
    now = [100.0]
    pacer = Pacer(2.0, clock=lambda: now[0])
    assert pacer.delay_s(5_000_000_000) == 0.0  # the first chunk at once
    assert pacer.delay_s(7_000_000_000) == pytest.approx(1.0)
    now[0] += 3.0  # late: the next chunk is not pushed back
    assert pacer.delay_s(9_000_000_000) == 0.0
    assert pacer.delay_s(13_000_000_000) == pytest.approx(1.0)
    assert Pacer(None).delay_s(10**18) == 0.0
    with pytest.raises(ValueError):
        Pacer(0.0)
    assert link_time_ns(10, 11_520, 11_520) == 10 + 1_000_000_000
