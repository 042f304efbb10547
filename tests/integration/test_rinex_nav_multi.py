"""Navigation files of every real recording with subframes against RTKLIB demo5 convbin's, per
system (GPS, GLONASS, Galileo); a parity-failed first copy of a subframe; a nav-only recording."""

from __future__ import annotations

import gzip
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from groundstation.errors import InputError
from groundstation.offline import rinex
from groundstation.solve import engine
from groundstation.solve.posfile import read_pos
from groundstation.solve.trajectory import Trajectory
from groundstation.ubx.fastraw import index_frames

# One worker runs this module's tests (pytest-xdist): its module fixture converts the real
# recordings, made once.
pytestmark = [pytest.mark.shared_data, pytest.mark.xdist_group("test_rinex_nav_multi")]

JD = "real/jdesbonnet__GNSS_RTK_data"
FILES = {
    "ubx_20080526": "real/tomojitakasu__RTKLIB/test/data/rcvraw/ubx_20080526.ubx",
    "rover-20181004-1237": f"{JD}/20181004/rover-20181004-1237.ubx.gz",
    "base-20181004-1236": f"{JD}/20181004/base-20181004-1236.ubx.gz",
    "rover-20181004-1532": f"{JD}/20181004/rover-20181004-1532.ubx.gz",
    "base-20181004-1452": f"{JD}/20181004/base-20181004-1452.ubx.gz",
    "rover-20181009-1221": f"{JD}/20181009/rover-20181009-1221.ubx.gz",
    "base-20181009-1220": f"{JD}/20181009/base-20181009-1220.ubx.gz",
    "rover-20181104-1634": f"{JD}/20181104/rover-20181104-1634.ubx.gz",
    "16dBatt_no_interference_coldstart":
        "real/nav-solutions__data/UBX/16dBatt_no_interference_coldstart.ubx.gz",
}
# Bases whose UBX frames are broken by interleaved RTCM3/NMEA: convbin loses frames after each
# damaged one (README "frames after damage"), we do not, so a GLONASS ephemeris can be completed
# from an earlier frame than convbin's (same data, earlier frame time) and one GPS ephemeris more.
DAMAGED = {"base-20181004-1236", "base-20181004-1452", "base-20181009-1220"}
# Per system: record fields where RTKLIB's choice differs from ours on purpose. GPS: 23 is the
# accuracy (RTKLIB prints its nominal URA table), 27 the transmission time (RTKLIB: HOW time;
# ours: start of subframe 1, 6 s earlier); see test_rinex_convbin.
GPS_OWN = {23, 27}
GLO_TOF = 2

Records = dict[tuple[str, str], list[list[float]]]


def nav_records(path: Path) -> Records:
    """(satellite, epoch text) → every record's values, RINEX 3 navigation file body."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        body = f.read().split("END OF HEADER")[1].splitlines()[1:]
    out: Records = {}
    key = ("", "")
    for raw in body:
        ln = raw.replace("D", "E")
        if ln[:1].isalpha():
            key = (ln[:3], ln[4:23])
            out.setdefault(key, []).append(
                [float(ln[23 + 19 * k : 42 + 19 * k]) for k in range(3)])
        else:
            out[key][-1].extend(float(ln[4 + 19 * k : 23 + 19 * k]) for k in range(4)
                                if ln[4 + 19 * k : 23 + 19 * k].strip())
    return out


def _differences(ours: Records, ref: Records, system: str, stem: str) -> list[str]:
    o = {k: v for k, v in ours.items() if k[0][0] == system}
    r = {k: v for k, v in ref.items() if k[0][0] == system}
    problems = [f"{k}: missing" for k in sorted(set(r) - set(o))]
    extra = sorted(set(o) - set(r))
    if extra and not (stem in DAMAGED and system == "G" and len(extra) <= 1):
        problems += [f"{k}: not in convbin's" for k in extra]
    for k in sorted(set(o) & set(r)):
        if len(o[k]) != len(r[k]):
            problems.append(f"{k}: {len(o[k])} records, convbin {len(r[k])}")
        a, b = o[k][0], r[k][0]
        if len(a) != len(b):
            problems.append(f"{k}: {len(a)} values, convbin {len(b)}")
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            if system == "G" and i in GPS_OWN:
                continue
            # an earlier (or later) frame of the same ephemeris: whole 30 s frames apart
            if (system == "R" and i == GLO_TOF and stem in DAMAGED
                    and (x - y) % 30 == 0 and abs(x - y) <= 600):
                continue
            if not math.isclose(x, y, rel_tol=1e-11, abs_tol=1e-20):
                problems.append(f"{k}[{i}]: ours {x!r}, convbin {y!r}")
    return problems


@pytest.fixture(scope="module")
def converted(
    shared_data: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, rinex.RinexResult]:
    out = tmp_path_factory.mktemp("nav")
    return {stem: rinex.convert(shared_data / rel, out) for stem, rel in FILES.items()}


@pytest.mark.parametrize("stem", list(FILES))
def test_every_convbin_record_per_system(
    converted: dict[str, rinex.RinexResult], shared_data: Path, stem: str
) -> None:
    res = converted[stem]
    ours = nav_records(res.nav_path)
    ref = nav_records(shared_data / "reference" / "convbin_rinex" / f"{stem}.nav.gz")
    counts = {s: sum(1 for k in ref if k[0][0] == s) for s in "GREC"}
    for system in "GREC":
        assert _differences(ours, ref, system, stem) == [], system
    # What convbin has, we have (its SBAS and QZSS records excepted: not decoded here).
    assert dict(res.other_ephemerides) == {s: n for s, n in counts.items() if n and s != "G"}
    assert res.nav_path.read_text().splitlines()[0][40:60].rstrip() == (
        "M: Mixed" if len([s for s in "GREC" if counts[s]]) > 1 else "G: GPS")


def _frames(data: bytes) -> list[tuple[int, int, int, int]]:
    idx = index_frames(data)
    return [(int(s), int(c), int(i), int(n))
            for s, c, i, n in zip(idx.start, idx.cls, idx.id, idx.length, strict=True)]


def _fix_checksum(buf: bytearray, start: int, length: int) -> None:
    a = b = 0
    for byte in buf[start + 2 : start + 6 + length]:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    buf[start + 6 + length] = a
    buf[start + 7 + length] = b


def test_subframe_whose_first_copy_fails_parity_is_used_from_a_later_copy(
    shared_data: Path, tmp_path: Path
) -> None:
    """A bit error in the HOW of the first copy of a subframe 1 (the HOW is not part of the
    duplicate key): the clean copy 30 s later must still complete the ephemeris."""
    data = rinex.read_recording(shared_data / FILES["rover-20181004-1237"])
    buf = bytearray(data)
    target = None
    for start, cls, mid, n in _frames(data):
        p = data[start + 6 : start + 6 + n]
        if (cls, mid) != (0x02, 0x13) or p[0] != 0 or n < 48:
            continue
        how = struct.unpack_from("<I", p, 12)[0]
        if (how >> 8) & 7 == 1:  # subframe 1
            target = (start, n)
            break
    assert target is not None
    start, n = target
    how_at = start + 6 + 12
    struct.pack_into("<I", buf, how_at, struct.unpack_from("<I", buf, how_at)[0] ^ (1 << 20))
    _fix_checksum(buf, start, n)
    damaged = tmp_path / "damaged.ubx"
    damaged.write_bytes(bytes(buf))
    clean = rinex.convert(shared_data / FILES["rover-20181004-1237"], tmp_path / "clean")
    res = rinex.convert(damaged, tmp_path / "out")
    assert res.nav_parity_errors == clean.nav_parity_errors + 1
    got, want = nav_records(res.nav_path), nav_records(clean.nav_path)
    assert got.keys() == want.keys() and res.ephemerides == clean.ephemerides == 14
    changed = [k for k in want if got[k] != want[k]]
    assert len(changed) == 1
    # The same ephemeris, transmitted by the next copy of subframe 1: 30 s later.
    a, b = got[changed[0]][0], want[changed[0]][0]
    assert a[:27] == b[:27] and a[28:] == b[28:] and a[27] == b[27] + 30


@pytest.mark.parametrize(("stem", "gps", "others"), [
    ("rover-20181009-1221", 15, (("R", 18),)),
    ("16dBatt_no_interference_coldstart", 9, (("E", 19),)),
])
def test_recording_with_navigation_data_only_gives_a_nav_file(
    shared_data: Path, tmp_path: Path, stem: str, gps: int, others: tuple[tuple[str, int], ...]
) -> None:
    """Only the RXM-SFRBX frames of a recording: the same records as from the whole recording
    (the GLONASS day comes from the GPS subframes), and no observation file."""
    src = shared_data / FILES[stem]
    data = rinex.read_recording(src)
    only = b"".join(data[s : s + n + 8] for s, c, i, n in _frames(data) if (c, i) == (2, 0x13))
    cut = tmp_path / "sfrbx-only.ubx"
    cut.write_bytes(only)
    full = rinex.convert(src, tmp_path / "full")
    res = rinex.convert(cut, tmp_path / "cut")
    assert not res.obs_written and res.epochs == 0 and not res.obs_path.exists()
    assert res.nav_path.exists()
    assert res.ephemerides == full.ephemerides == gps
    assert res.other_ephemerides == full.other_ephemerides == others
    assert nav_records(res.nav_path) == nav_records(full.nav_path)


def test_no_navigation_and_no_measurements_is_a_clear_error(tmp_path: Path) -> None:
    empty = tmp_path / "nothing.ubx"
    empty.write_bytes(b"\xb5\x62\x01\x06\x00\x00\x07\x16" * 3)
    with pytest.raises(InputError, match="no navigation data"):
        rinex.convert(empty, tmp_path)


def _pyrtklib5_nav(src: Path, out: Path) -> Path:
    """RTKLIB-EX's own navigation file of a recording (``convrnx``, as convbin runs it)."""
    p5 = pytest.importorskip("pyrtklib5")
    opt = p5.rnxopt_t()
    opt.rnxver, opt.navsys = 304, 0xFF
    nav = out / "pyrtklib5.nav"
    assert p5.convrnx(4, opt, str(src), [str(out / "pyrtklib5.obs"), str(nav)] + [""] * 7) == 1
    return nav


def test_beidou_and_galileo_of_a_recent_receiver_equal_rtklib_ex(
    shared_data: Path, tmp_path: Path
) -> None:
    """gnss_1730 (2025, BeiDou D1 and Galileo I/NAV + F/NAV) has no convbin reference file:
    RTKLIB-EX itself (pyrtklib5 2.5.0, the engine) converts it here.

    Known differences: 2.5.0 prints the broadcast AODE where 2.5.1 (the convbin of the reference
    files) and we derive it from toc (row 1, first value), and 2.5.0 drops BeiDou PRNs above 46.
    We decode Galileo I/NAV, not F/NAV (E5a): compare with RTKLIB's I/NAV records (data source
    513); ours has two more (E08, E14 at 17:20, orbit equal to RTKLIB's F/NAV records of the
    same IODnav) which 2.5.0 does not write.
    """
    src = shared_data / "real/rtklibexplorer__GNSS_IMU/data/walk_0827/gnss_1730.ubx"
    ours = nav_records(rinex.convert(src, tmp_path).nav_path)
    ref = nav_records(_pyrtklib5_nav(src, tmp_path))
    c_ours = {k: v for k, v in ours.items() if k[0][0] == "C"}
    c_ref = {k: v for k, v in ref.items() if k[0][0] == "C"}
    assert sorted(c_ours) == sorted([*c_ref, ("C50", "2025 08 28 17 00 00")])
    assert len(c_ref) == 7
    for k, (r,) in c_ref.items():
        (o,) = c_ours[k]
        assert o[3] == 85 and r[3] == 1  # AODE: int(61200 / 720) % 240 vs broadcast
        assert all(math.isclose(a, b, rel_tol=1e-11, abs_tol=1e-20)
                   for i, (a, b) in enumerate(zip(o, r, strict=True)) if i != 3), k
    e_ref = {k: [v for v in vs if v[20] == 513] for k, vs in ref.items() if k[0][0] == "E"}
    e_ref = {k: v for k, v in e_ref.items() if v}
    e_ours = {k: v for k, v in ours.items() if k[0][0] == "E"}
    assert len(e_ref) == 5 and set(e_ref) <= set(e_ours) and len(e_ours) == 7
    for k, (r,) in e_ref.items():
        (o,) = e_ours[k]
        assert all(math.isclose(a, b, rel_tol=1e-11, abs_tol=1e-20)
                   for a, b in zip(o, r, strict=True)), k


JD_1009 = ("rover-20181009-1221", "base-20181009-1220")
BASE_1009_XYZ = (3774696.5547, -596647.9083, 5089485.6511)
JD_POS = "reference/rnx2rtkp_pos/jd_20181009_kin_vs_M8Pbase_svin.pos.gz"


def _solve(obs: dict[str, str], nav: dict[str, str], work: Path) -> Trajectory:
    """demo5 with our default options on the given RINEX texts of the 2018-10-09 flight."""
    work.mkdir(parents=True)
    for stem in JD_1009:
        (work / f"{stem}.obs").write_text(obs[stem])
        (work / f"{stem}.nav").write_text(nav[stem])
    run = engine.run_engine("demo5", work / f"{JD_1009[0]}.obs", work / f"{JD_1009[1]}.obs",
                            BASE_1009_XYZ, work / "work")
    return read_pos(run.pos_path)


@pytest.mark.slow
def test_the_real_flight_solves_as_well_from_our_navigation_files(
    shared_data: Path, tmp_path: Path
) -> None:
    """2018-10-09 with demo5 and our default options.

    1. On convbin's observations, our nav files (GPS + GLONASS) give the same solution as
       convbin's nav files: same quality on every epoch, fixed and float positions within
       0.1 mm (before this
       work our nav had no GLONASS: 1626 fixed, 7.9 cm p95).
    2. From our RINEX alone (``run_engine`` on the .ubx files, acceleration noise set from the
       measured dynamics, forward and backward merged by ``engine/combine.py``): 1813 fixed
       epochs (convbin's RINEX: 1802) and 1.89 cm p95 against the demo5 reference where both
       are fixed (convbin's: 1.69 cm). Our base RINEX has 76 epochs more than convbin's (those
       we recover after damaged frames, README "frames after damage"): the solution moves near
       them, where the reference (made without them) cannot agree.
    """
    ref_dir = shared_data / "reference" / "convbin_rinex"
    conv = {ext: {s: gzip.decompress((ref_dir / f"{s}.{ext}.gz").read_bytes()).decode()
                  for s in JD_1009} for ext in ("obs", "nav")}
    ours_dir = tmp_path / "ours"
    ours_nav = {s: rinex.convert(shared_data / FILES[s], ours_dir).nav_path.read_text()
                for s in JD_1009}
    a = _solve(conv["obs"], conv["nav"], tmp_path / "convbin")
    b = _solve(conv["obs"], ours_nav, tmp_path / "our_nav")
    assert np.array_equal(a.quality, b.quality) and int(np.sum(a.quality == 1)) == 1802
    # Fixed and float epochs: the same. (DGPS epochs move by centimetres: our nav file carries
    # the broadcast GPS ionosphere, which convbin writes for none of the u-blox 8 logs.)
    carrier = a.quality <= 2
    assert np.abs(a.ecef_m[carrier] - b.ecef_m[carrier]).max() <= 1.5e-4  # the printed digit
    run = engine.run_engine(
        "demo5", shared_data / FILES[JD_1009[0]], shared_data / FILES[JD_1009[1]],
        BASE_1009_XYZ, tmp_path / "from_ubx")
    ours, ref = read_pos(run.pos_path), read_pos(shared_data / JD_POS)
    t_o, t_r = (np.round(t.t_gps_ns / 1e6).astype(np.int64) for t in (ours, ref))
    _, i, j = np.intersect1d(t_o, t_r, return_indices=True)
    both = (ours.quality[i] == 1) & (ref.quality[j] == 1)
    d = np.linalg.norm(ours.ecef_m[i][both] - ref.ecef_m[j][both], axis=1)
    n_fix, p95 = int(np.sum(ours.quality == 1)), float(np.percentile(d, 95))
    print(f"from our RINEX: {n_fix} fixed of {len(ours)}, p95 {p95 * 100:.2f} cm")
    assert n_fix >= 1802 and p95 <= 0.02
