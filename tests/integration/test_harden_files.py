"""Crafted and huge files through the real command line: a looping-EXIF photo is skipped by
``solve``; a 2 GB sparse recording is read in bounded memory."""

from __future__ import annotations

import datetime as dt
import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from peers import REPO
from poison import looping_exif_jpeg

from groundstation.solve import exif

JD = "real/jdesbonnet__GNSS_RTK_data/20181009"
POS = "reference/rnx2rtkp_pos/jd_20181009_kin_vs_M8Pbase_svin.pos.gz"
RSS_LIMIT_MB = 500


def _cli(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "groundstation.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "PYTHONPATH": str(REPO)})


@pytest.mark.shared_data
def test_solve_finishes_with_the_looping_exif_photo_skipped(
    shared_data: Path, tmp_path: Path,
) -> None:
    pics = tmp_path / "photos"
    pics.mkdir()
    (pics / "IMG_0000.JPG").write_bytes(looping_exif_jpeg())
    for i in range(1, 4):
        (pics / f"IMG_{i:04d}.JPG").write_bytes(
            exif.make_jpeg(dt.datetime(2018, 10, 9, 12, 30, i)))
    before = {p.name: p.read_bytes() for p in pics.iterdir()}
    proc = _cli("solve", "--no-pdf",
                str(shared_data / JD / "rover-20181009-1221.ubx.gz"), "--positions",
                str(shared_data / POS), "--photos", str(pics), "--out", str(tmp_path / "out"),
                "--no-progress", cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "1 photos skipped (no usable EXIF time)" in proc.stdout
    assert "IMG_0000.JPG" in (tmp_path / "out" / "cameras.csv").read_text()
    assert {p.name: p.read_bytes() for p in pics.iterdir()} == before


@pytest.fixture(scope="module")
def sparse_2gb(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("big") / "big.ubx"
    with path.open("wb") as f:
        f.truncate(2 << 30)  # sparse: no disk used
    return path


def _max_rss_mb(*args: str, cwd: Path, cap_gb: float = 0.0
                ) -> tuple[float, subprocess.CompletedProcess[str]]:
    """Peak RSS of one command (the children's ``ru_maxrss`` around its run); ``cap_gb``
    limits its address space (a reader that collects everything then fails early instead of
    taking gigabytes from the machine)."""
    cap = int(cap_gb * (1 << 30))
    code = (
        "import resource, subprocess, sys\n"
        f"if {cap}: resource.setrlimit(resource.RLIMIT_AS, ({cap}, {cap}))\n"
        "p = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
        "sys.stdout.write(p.stdout); sys.stderr.write(p.stderr)\n"
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr)\n"
        "sys.exit(p.returncode)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, sys.executable, "-m", "groundstation.cli", *args],
        cwd=cwd, capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    *rest, last = proc.stderr.strip().splitlines()
    proc.stderr = "\n".join(rest)
    return int(last) / 1024, proc


@pytest.mark.slow
def test_inspect_of_a_2gb_sparse_file_stays_under_500mb(sparse_2gb: Path) -> None:
    rss, proc = _max_rss_mb("inspect", str(sparse_2gb), cwd=sparse_2gb.parent)
    print(f"inspect 2 GB sparse: peak RSS {rss:.0f} MB")
    # Read to the end, streaming, then one clear line: zeros hold no UBX frame.
    assert proc.returncode == 2 and "no UBX frames in this file" in proc.stderr, proc.stderr
    assert rss < RSS_LIMIT_MB


@pytest.mark.slow
def test_rinex_of_a_2gb_sparse_file_stays_under_500mb(sparse_2gb: Path) -> None:
    rss, proc = _max_rss_mb("rinex", str(sparse_2gb), "-o", str(sparse_2gb.parent / "out"),
                            "--progress", "never", cwd=sparse_2gb.parent, cap_gb=3.0)
    print(f"rinex 2 GB sparse: peak RSS {rss:.0f} MB")
    # Read to the end in blocks (only frames are kept), then one clear line: nothing to convert.
    assert "Traceback" not in proc.stderr
    assert proc.returncode == 2 and "no raw measurements" in proc.stderr, proc.stderr
    assert rss < RSS_LIMIT_MB



MCAP_MAGIC = b"\x89MCAP0\r\n"
HUGE = 1 << 60


def _record(op: int, body: bytes, claimed: int | None = None) -> bytes:
    return bytes([op]) + struct.pack("<Q", len(body) if claimed is None else claimed) + body


def _huge_header_mcap() -> bytes:
    """The MCAP header record claims 2^60 bytes."""
    return MCAP_MAGIC + _record(0x01, b"\x00" * 100, HUGE)


def _huge_chunk_mcap() -> bytes:
    """A good header, then a chunk whose records claim 2^60 bytes (uncompressed size too)."""
    header = _record(0x01, struct.pack("<I", 0) + struct.pack("<I", 4) + b"gs-x")
    body = struct.pack("<QQQI", 0, 0, HUGE, 0) + struct.pack("<I", 0) + struct.pack("<Q", HUGE)
    return MCAP_MAGIC + header + _record(0x06, body + b"\x00" * 64)


CRAFTED_MCAP = {"huge-header": _huge_header_mcap, "huge-chunk": _huge_chunk_mcap}


@pytest.mark.parametrize("command", ["inspect", "rinex"])
@pytest.mark.parametrize("craft", sorted(CRAFTED_MCAP))
def test_an_mcap_record_claiming_2_60_bytes_is_one_clear_line(
    craft: str, command: str, tmp_path: Path
) -> None:
    path = tmp_path / "crafted.mcap"
    path.write_bytes(CRAFTED_MCAP[craft]())
    extra = ("-o", str(tmp_path / "out"), "--progress", "never") if command == "rinex" else ()
    proc = _cli(command, str(path), *extra, cwd=tmp_path, timeout=30)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr, proc.stderr
    assert len(lines) == 1 and lines[0].startswith(f"groundstation {command}: error:"), lines
    says = "no UBX frames" if command == "inspect" else "no raw measurements"
    assert says in lines[0]
    assert proc.returncode == 2


def test_a_chunk_claiming_2_60_bytes_ends_the_readable_part(tmp_path: Path) -> None:
    """A real recording whose second chunk claims 2^60 bytes: the frames before it are read
    (as for a torn file), nothing is allocated for the claim."""
    data = bytearray((REPO / "tests" / "data" / "lea6t-torn.mcap").read_bytes())
    pos, chunks = len(MCAP_MAGIC), []
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06:
            chunks.append(pos)
        pos += 9 + length
    assert len(chunks) >= 2
    struct.pack_into("<Q", data, chunks[1] + 1, HUGE)
    path = tmp_path / "crafted.mcap"
    path.write_bytes(data)
    proc = _cli("inspect", "--json", str(path), cwd=tmp_path, timeout=30)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    whole = _cli("inspect", "--json", str(REPO / "tests" / "data" / "lea6t-torn.mcap"),
                 cwd=tmp_path, timeout=30)
    frames, all_frames = json.loads(proc.stdout)["frames"], json.loads(whole.stdout)["frames"]
    assert 0 < frames < all_frames
