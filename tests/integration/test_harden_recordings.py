"""Crafted MCAP recordings: a damaged middle is read past and said, parts stay in their directory.

Real recordings written by the session recorder, then damaged on disk the way a bad sector, a
bit flip or a bad copy would: a chunk whose compressed bytes or header are garbled, a chunk
record turned into an unknown one, an uncompressed chunk with changed bytes (only its CRC tells),
the chunk that defines the channels. Finished files (the summary names every chunk) and unfinished
ones (a linear search for the next whole chunk) both go on after the damage, and every tool says
how much was skipped: the warning line (byte range, time span), ``inspect`` and ``inspect
--json``; ``rinex`` and the solver read every epoch and mark after it.

A session's later parts are followed only inside the recording's own directory: a neighbouring
part's metadata naming ``../secret.txt`` or an absolute path, or a part or sidecar that is a
symbolic link out of the directory, is refused with a warning and never read.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import ChunkIndex
from peers import cli_env
from streams import flight_stream, tim_tm2

from groundstation.offline.inspect import inspect_path
from groundstation.solve.flight import read_flight
from groundstation.storage.mcapio import McapFileWriter, ReadReport, iter_messages
from groundstation.storage.reading import Recording, iter_chunks
from groundstation.storage.session import SessionRecorder

# One worker runs this module's tests (pytest-xdist):
# its module fixture records a flight, made once.
pytestmark = pytest.mark.xdist_group("test_harden_recordings")

T0_NS = 1_700_000_000_000_000_000
FRAME_NS = 10_000_000  # each frame its own log time, so a lost chunk's frames are known
RXM_RAW = b"\xb5\x62\x02\x10"
TIM_TM2 = b"\xb5\x62\x0d\x03"


class Clock:
    def __init__(self) -> None:
        self.now = T0_NS

    def __call__(self) -> int:
        return self.now


def record(out: Path, frames: list[bytes], *, compression: str = "zstd",
           station: str = "st1", start_ns: int = T0_NS) -> SessionRecorder:
    """``frames`` recorded as a live session would be, in many small chunks."""
    clock = Clock()
    clock.now = start_ns
    rec = SessionRecorder(out, station, chunk_size_bytes=1024, compression=compression,
                          clock=clock)
    rec.open()
    for i, frame in enumerate(frames):
        clock.now = start_ns + i * FRAME_NS
        rec.write_raw(frame, clock.now)
        if i % 7 == 6:
            rec.flush()
    rec.close()
    return rec


def chunk_indexes(path: Path) -> list[ChunkIndex]:
    """The chunks of a finished file, from the mcap library's own seeking reader."""
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def unfinished(path: Path, dest: Path) -> Path:
    """``path`` as its writer left it before the summary (killed after its last flush)."""
    data = path.read_bytes()
    summary_start = int.from_bytes(data[-28:-20], "little")  # the footer says where
    dest.write_bytes(data[: summary_start - 13])  # without the data-end record too
    assert not dest.read_bytes().endswith(b"\x89MCAP0\r\n")
    return dest


def survivors(frames: list[bytes], lost: ChunkIndex) -> list[bytes]:
    """The frames outside a lost chunk (their log times outside its span)."""
    return [f for i, f in enumerate(frames)
            if not lost.message_start_time <= T0_NS + i * FRAME_NS <= lost.message_end_time]


def garble(path: Path, dest: Path, chunk: ChunkIndex, *, at: int | None = None,
           patch: bytes = b"\x5a" * 16) -> Path:
    """A copy of ``path`` with bytes of ``chunk`` XOR-ed (default: in its middle)."""
    data = bytearray(path.read_bytes())
    start = chunk.chunk_start_offset + (chunk.chunk_length // 2 if at is None else at)
    for k, b in enumerate(patch):
        data[start + k] ^= b
    dest.write_bytes(data)
    return dest


def raw_of(path: Path) -> bytes:
    return b"".join(c for c, _ in iter_chunks(path))


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[bytes]]:
    """A finished 60 s flight (300 epochs, a mark every second) in about 100 chunks."""
    _, frames = flight_stream(300)
    rec = record(tmp_path_factory.mktemp("flight"), frames)
    (mcap,) = rec.stats.files
    assert len(chunk_indexes(mcap)) > 50
    return mcap, frames


def middle(mcap: Path) -> ChunkIndex:
    chunks = chunk_indexes(mcap)
    return chunks[len(chunks) // 2]


@pytest.mark.parametrize("finished", [True, False], ids=["finished", "unfinished"])
@pytest.mark.parametrize("damage", ["compressed bytes", "record length", "record type"])
def test_a_damaged_chunk_in_the_middle_is_read_past_and_said(
    flight: tuple[Path, list[bytes]], tmp_path: Path, caplog: pytest.LogCaptureFixture,
    finished: bool, damage: str,
) -> None:
    mcap, frames = flight
    lost = middle(mcap)
    patch = {"compressed bytes": (None, b"\x5a" * 16),
             "record length": (1, (10**9).to_bytes(8, "little")),  # XOR: a huge length
             "record type": (0, b"\x80")}[damage]  # opcode 0x06 -> 0x86 (a user record)
    bad = garble(mcap, tmp_path / "bad.mcap", lost, at=patch[0], patch=patch[1])
    if not finished:
        bad = unfinished(bad, tmp_path / "bad-unfinished.mcap")
    with caplog.at_level(logging.WARNING, "groundstation.storage"):
        recording = Recording(bad)
        got = b"".join(c for c, _ in recording.chunks())
    assert got == b"".join(survivors(frames, lost))  # everything after the damage is read
    (skipped,) = recording.skipped
    assert skipped.start_byte == lost.chunk_start_offset
    assert skipped.end_byte > lost.chunk_start_offset + lost.chunk_length
    assert not skipped.to_end
    if finished:  # the summary names the lost chunk and its span
        assert skipped.chunks == 1
        assert (skipped.lost_first_ns, skipped.lost_last_ns) == (
            lost.message_start_time, lost.message_end_time)
    else:  # bounded by what was read on either side
        assert skipped.chunks is None
        assert skipped.read_before_ns == lost.message_start_time - FRAME_NS
        assert skipped.read_after_ns == lost.message_end_time + FRAME_NS
    warning = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warning) == 1
    assert f"bytes {lost.chunk_start_offset:,} .. {skipped.end_byte:,}" in warning[0]
    assert "UTC" in warning[0] and "read on after it" in warning[0]


def test_an_uncompressed_chunk_with_changed_bytes_is_caught_by_its_crc(
    tmp_path: Path, caplog: pytest.LogCaptureFixture,
) -> None:
    """Without the CRC check, the changed bytes came back as if recorded."""
    _, frames = flight_stream(100)
    (mcap,) = record(tmp_path / "rec", frames, compression="none").stats.files
    lost = middle(mcap)
    bad = garble(mcap, tmp_path / "bad.mcap", lost, patch=b"\x01")
    with caplog.at_level(logging.WARNING, "groundstation.storage"):
        got = raw_of(bad)
    assert got == b"".join(survivors(frames, lost))
    assert "CRC mismatch" in caplog.text


@pytest.mark.parametrize("compression", ["none", "lz4"])
def test_an_unfinished_file_of_other_compressions_is_read_past_its_damage(
    tmp_path: Path, compression: str,
) -> None:
    """The linear search for the next chunk knows each compression's first bytes."""
    _, frames = flight_stream(100)
    (mcap,) = record(tmp_path / "rec", frames, compression=compression).stats.files
    lost = middle(mcap)
    bad = unfinished(garble(mcap, tmp_path / "bad.mcap", lost), tmp_path / "torn.mcap")
    recording = Recording(bad)
    assert b"".join(c for c, _ in recording.chunks()) == b"".join(survivors(frames, lost))
    (skipped,) = recording.skipped
    assert skipped.start_byte == lost.chunk_start_offset and not skipped.to_end


def test_the_chunk_defining_the_channels_lost(
    tmp_path: Path, caplog: pytest.LogCaptureFixture,
) -> None:
    """The first chunk holds the channel records. A finished file's summary repeats them, so
    every later message is still read; an unfinished file cannot name their topic: they are
    counted and said, not dropped quietly."""
    _, frames = flight_stream(100)
    (mcap,) = record(tmp_path / "rec", frames).stats.files
    first = chunk_indexes(mcap)[0]
    bad = garble(mcap, tmp_path / "bad.mcap", first)
    assert raw_of(bad) == b"".join(survivors(frames, first))
    torn = unfinished(bad, tmp_path / "torn.mcap")
    report = ReadReport()
    with caplog.at_level(logging.WARNING, "groundstation.storage"):
        assert list(iter_messages(torn, ["/ubx/raw"], report)) == []
    assert report.orphan_messages == len(survivors(frames, first))
    assert f"{report.orphan_messages} messages on channels defined only in the skipped" \
        in caplog.text
    assert inspect_path(torn).orphan_messages == report.orphan_messages


def test_an_unfinished_file_damaged_in_its_last_chunk_says_so(
    tmp_path: Path, caplog: pytest.LogCaptureFixture,
) -> None:
    """Not a torn tail (the chunk is whole but garbled): the rest of the file is lost, said."""
    _, frames = flight_stream(60)
    (mcap,) = record(tmp_path / "rec", frames).stats.files
    last = chunk_indexes(mcap)[-1]
    bad = unfinished(garble(mcap, tmp_path / "bad.mcap", last), tmp_path / "torn.mcap")
    with caplog.at_level(logging.WARNING, "groundstation.storage"):
        recording = Recording(bad)
        got = b"".join(c for c, _ in recording.chunks())
    assert got == b"".join(survivors(frames, last))
    (skipped,) = recording.skipped
    assert skipped.to_end and skipped.end_byte == bad.stat().st_size
    assert "nothing after it could be read" in caplog.text


def test_a_torn_tail_stays_quiet(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A killed writer's last chunk runs past the end of the file: the expected end of an
    unfinished recording, not damage (no warning, nothing listed as skipped)."""
    _, frames = flight_stream(60)
    (mcap,) = record(tmp_path / "rec", frames).stats.files
    last = chunk_indexes(mcap)[-1]
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(mcap.read_bytes()[: last.chunk_start_offset + last.chunk_length // 2])
    with caplog.at_level(logging.WARNING, "groundstation.storage"):
        recording = Recording(torn)
        got = b"".join(c for c, _ in recording.chunks())
    assert got == b"".join(survivors(frames, last))
    assert recording.skipped == [] and caplog.text == ""


def test_a_damaged_stretch_is_said_once_however_often_it_is_read(
    flight: tuple[Path, list[bytes]], tmp_path: Path, caplog: pytest.LogCaptureFixture,
) -> None:
    """``solve`` reads a recording for its marks, then for RINEX: one warning, not two."""
    mcap, _ = flight
    bad = garble(mcap, tmp_path / "bad.mcap", middle(mcap))
    with caplog.at_level(logging.WARNING, "groundstation.storage"):
        for _ in range(3):
            recording = Recording(bad)
            for _chunk in recording.chunks():
                pass
            assert len(recording.skipped) == 1  # listed every time
    assert len([r for r in caplog.records if r.levelno == logging.WARNING]) == 1


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "groundstation.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120, env=cli_env())


def test_inspect_rinex_and_the_solver_read_past_a_damaged_chunk(
    flight: tuple[Path, list[bytes]], tmp_path: Path, caplog: pytest.LogCaptureFixture,
) -> None:
    """Before: all three stopped at the damaged chunk, exit 0, no word."""
    mcap, frames = flight
    lost = middle(mcap)
    bad = garble(mcap, tmp_path / "bad.mcap", lost)
    kept = survivors(frames, lost)
    epochs = sum(f.startswith(RXM_RAW) for f in kept)
    marks = sum(f.startswith(TIM_TM2) for f in kept)
    assert 0 < epochs < sum(f.startswith(RXM_RAW) for f in frames)
    where = f"bytes {lost.chunk_start_offset:,} .. "

    js = _cli("inspect", "--json", str(bad), cwd=tmp_path)
    assert js.returncode == 0, js.stderr
    summary = json.loads(js.stdout)
    assert summary["epochs"] == epochs
    (skipped,) = summary["skipped"]
    assert skipped["start_byte"] == lost.chunk_start_offset and skipped["chunks"] == 1
    assert where in js.stderr and "WARNING" in js.stderr
    text = _cli("inspect", str(bad), cwd=tmp_path)
    assert "unread    1 damaged stretch of the file skipped" in text.stdout
    assert where in text.stdout

    rx = _cli("rinex", str(bad), "--out-dir", str(tmp_path / "rinex"), cwd=tmp_path)
    assert rx.returncode == 0, rx.stderr
    assert f"{epochs} epochs" in rx.stdout and where in rx.stderr

    with caplog.at_level(logging.WARNING, "groundstation.storage"):
        records = read_flight(bad)
    assert len(records.timemarks) == marks
    assert where in caplog.text


# -- a session's parts stay in their directory -------------------------------------------------

SECRET = tim_tm2(4242, 2300, 1000, 0, None)  # a valid frame: read, it would show in the bytes


def neighbour(directory: Path, rec: SessionRecorder, *, sidecar: str, name: str = "") -> Path:
    """A crafted part 2 of ``rec``'s session in ``directory``, naming ``sidecar``."""
    path = directory / (name or f"{rec.station}_29991231T235959Z.mcap")
    with McapFileWriter(path) as w:
        w.add_metadata("groundstation", {
            "station": rec.station, "session_id": rec.session_id, "part": "2",
            "sidecar": sidecar,
        })
    return path


@pytest.fixture()
def session(tmp_path: Path) -> tuple[Path, SessionRecorder, bytes, Path]:
    """A one-part session in ``flights/`` and a secret file beside the directory."""
    data, frames = flight_stream(20)
    rec = record(tmp_path / "flights", frames)
    secret = tmp_path / "secret.txt"
    secret.write_bytes(SECRET)
    return tmp_path / "flights", rec, data, secret


@pytest.mark.parametrize("named", ["../secret.txt", "../secret.ubx", "ABSOLUTE", "sub/x.ubx",
                                   "..", "a\\..\\b.ubx"])
def test_a_sidecar_named_as_a_path_in_a_parts_metadata_is_refused(
    session: tuple[Path, SessionRecorder, bytes, Path], caplog: pytest.LogCaptureFixture,
    named: str,
) -> None:
    flights, rec, data, secret = session
    (flights.parent / "secret.ubx").write_bytes(SECRET)
    (flights / "sub").mkdir()
    (flights / "sub" / "x.ubx").write_bytes(SECRET)
    name = str(secret) if named == "ABSOLUTE" else named
    neighbour(flights, rec, sidecar=name)
    (side,) = rec.stats.sidecars
    with caplog.at_level(logging.WARNING, "groundstation.reading"):
        got = raw_of(side)
    assert got == data  # part 1's sidecar; nothing of the "sidecar" part 2 names
    assert SECRET not in got
    assert f"names its sidecar {name!r}" in caplog.text and "refused" in caplog.text


def test_a_part_or_sidecar_linked_out_of_the_directory_is_not_followed(
    session: tuple[Path, SessionRecorder, bytes, Path], caplog: pytest.LogCaptureFixture,
) -> None:
    flights, rec, data, secret = session
    outside = flights.parent / "elsewhere"
    outside.mkdir()
    # part 2 itself a link to a real part lying elsewhere, with a real sidecar beside it
    (outside / "p2.ubx").write_bytes(SECRET)
    target = neighbour(outside, rec, sidecar="p2.ubx")
    linked = flights / target.name
    linked.symlink_to(target)
    (mcap,), (side,) = rec.stats.files, rec.stats.sidecars
    with caplog.at_level(logging.WARNING, "groundstation.reading"):
        assert Recording(mcap).parts == (mcap,)
        assert SECRET not in raw_of(side)
    assert "symbolic link out of the recording's directory" in caplog.text
    assert str(linked) in caplog.text
    # part 2 in the directory, its sidecar a link out of it
    linked.unlink()
    caplog.clear()
    neighbour(flights, rec, sidecar="p2.ubx")
    (flights / "p2.ubx").symlink_to(secret)
    with caplog.at_level(logging.WARNING, "groundstation.reading"):
        got = raw_of(side)
    assert got == data and SECRET not in got
    assert "the sidecar of part 2" in caplog.text and "refused" in caplog.text
    # a link that stays in the directory is still followed
    (flights / "p2.ubx").unlink()
    (flights / "real-p2.ubx").write_bytes(SECRET)
    os.symlink("real-p2.ubx", flights / "p2.ubx")
    assert raw_of(side) == data + SECRET


def test_the_solver_service_reads_no_part_outside_its_roots(
    session: tuple[Path, SessionRecorder, bytes, Path], tmp_path: Path,
) -> None:
    """The service checks the recording it is given against ``recording_roots``; the parts
    followed from there stay in that recording's directory, so inside the roots too."""
    from groundstation.solve.service import confine

    flights, rec, _, secret = session
    neighbour(flights, rec, sidecar=str(secret))
    (side,) = rec.stats.sidecars
    real, why = confine(side, (flights,))
    assert real is not None, why
    assert all(p.resolve().parent == flights.resolve() for p in Recording(real).parts)
    assert SECRET not in raw_of(real)
