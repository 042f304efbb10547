"""``groundstation rinex`` on every real recording against RTKLIB demo5 convbin's RINEX: values,
LLI, extra epochs, time-mark events, ephemerides and rnx2rtkp single-point solutions."""

from __future__ import annotations

import csv
import gzip
import math
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from groundstation.offline import rinex
from groundstation.offline.rinex import format as rinex_format
from groundstation.storage.reading import iter_chunks
from groundstation.ubx.fastraw import decode_raw, decode_rawx, index_frames

# One worker runs this module's tests (pytest-xdist): its module fixture converts the real
# recordings, made once.
pytestmark = [pytest.mark.shared_data, pytest.mark.xdist_group("test_rinex_convbin")]

FILES = {
    "ubx_20080526": "real/tomojitakasu__RTKLIB/test/data/rcvraw/ubx_20080526.ubx",
    "6P-raw-PPP": "real/tridge__pyUblox/data/6P-raw-PPP.ubx",
    "6P-raw-PPP-2": "real/tridge__pyUblox/data/6P-raw-PPP-2.ubx",
    "ublox-aek-4t": "real/gpsd__gpsd-mirror/test/daemon/ublox-aek-4t.log",
    "ublox-lea-4t": "real/gpsd__gpsd-mirror/test/daemon/ublox-lea-4t.log",
    "ublox-neo-m8t": "real/gpsd__gpsd-mirror/test/daemon/ublox-neo-m8t.log",
    "ublox-zed-f9p_hpg1.11": "real/gpsd__gpsd-mirror/test/daemon/ublox-zed-f9p_hpg1.11.log",
    "rover-20181004-1237": "real/jdesbonnet__GNSS_RTK_data/20181004/rover-20181004-1237.ubx.gz",
    "base-20181004-1236": "real/jdesbonnet__GNSS_RTK_data/20181004/base-20181004-1236.ubx.gz",
    "rover-20181004-1532": "real/jdesbonnet__GNSS_RTK_data/20181004/rover-20181004-1532.ubx.gz",
    "base-20181004-1452": "real/jdesbonnet__GNSS_RTK_data/20181004/base-20181004-1452.ubx.gz",
    "rover-20181009-1221": "real/jdesbonnet__GNSS_RTK_data/20181009/rover-20181009-1221.ubx.gz",
    "base-20181009-1220": "real/jdesbonnet__GNSS_RTK_data/20181009/base-20181009-1220.ubx.gz",
    "rover-20181104-1634": "real/jdesbonnet__GNSS_RTK_data/20181104/rover-20181104-1634.ubx.gz",
    "16dBatt_no_interference_coldstart":
        "real/nav-solutions__data/UBX/16dBatt_no_interference_coldstart.ubx.gz",
    "gnss_1730": "real/rtklibexplorer__GNSS_IMU/data/walk_0827/gnss_1730.ubx",
}
EXTRA_EPOCHS = {  # epochs recovered from frames convbin loses after damage
    "6P-raw-PPP": 12,
    "base-20181004-1236": 38,
    "base-20181004-1452": 119,
    "base-20181009-1220": 76,
}
# convbin (without -MULTICODE) merges signals into X codes; ours keep one code per signal.
MERGED = {("G", "2L"): "2X", ("G", "2S"): "2X", ("E", "1C"): "1X", ("E", "1B"): "1X",
          ("E", "7I"): "7X", ("E", "7Q"): "7X", ("E", "5I"): "5X", ("E", "5Q"): "5X",
          ("J", "2S"): "2X", ("J", "2L"): "2X"}  # fmt: skip


@dataclass
class Converted:
    stem: str
    src: Path
    result: rinex.RinexResult
    ref_obs: Path
    ref_nav: Path


@pytest.fixture(scope="module")
def converted(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Converted]:
    out = tmp_path_factory.mktemp("rinex")
    ref = shared_data / "reference" / "convbin_rinex"
    done = {}
    for stem, rel in FILES.items():
        res = rinex.convert(shared_data / rel, out)
        done[stem] = Converted(
            stem, shared_data / rel, res, ref / f"{stem}.obs.gz", ref / f"{stem}.nav.gz"
        )
    return done


def _values(ep: rinex.ObsEpoch) -> dict[tuple[str, str], tuple[str, str]]:
    out = {}
    for sat, rec in ep.sats.items():
        for t, v in rec.items():
            out[(sat, t[0] + MERGED.get((sat[0], t[1:]), t[1:]))] = v
    return out


def _compare(ours: list[rinex.ObsEpoch], ref: list[rinex.ObsEpoch], lli: bool) -> list[str]:
    """Differences: every ref value must be ours too (``lli``: the LLI as well)."""
    by_time = {e.time: e for e in ours if e.flag == 0}
    problems = []
    for e in ref:
        if e.flag != 0:
            continue
        mine = by_time.get(e.time)
        if mine is None:
            problems.append(f"{e.time}: epoch missing")
            continue
        mv = _values(mine)
        for (sat, t), (val, flag) in _values(e).items():
            got = mv.get((sat, t), ("", ""))
            if got[0] != val or (lli and got[1] != flag):
                problems.append(f"{e.time} {sat} {t}: convbin {val!r}/{flag!r}, ours {got}")
    return problems


@pytest.mark.parametrize("stem", [s for s in FILES if s != "gnss_1730"])
def test_every_convbin_epoch_with_identical_values(
    converted: dict[str, Converted], stem: str
) -> None:
    c = converted[stem]
    _, ours = rinex.read_obs3(c.result.obs_path)
    _, ref = rinex.read_obs3(c.ref_obs)
    # Pseudorange, phase, Doppler, C/N0 always; the LLI too unless recovered epochs (which
    # convbin never saw) changed the lock-time history: checked on convbin's epochs below.
    assert _compare(ours, ref, lli=stem not in EXTRA_EPOCHS) == []
    ref_times = {e.time for e in ref if e.flag == 0}
    extra = [e.time for e in ours if e.flag == 0 and e.time not in ref_times]
    assert len(extra) == EXTRA_EPOCHS.get(stem, 0), extra[:5]
    assert c.result.epochs == len(ref_times) + len(extra)


@pytest.mark.parametrize("stem", sorted(EXTRA_EPOCHS))
def test_lli_identical_on_the_epochs_convbin_decoded(
    converted: dict[str, Converted], stem: str, tmp_path: Path
) -> None:
    """With the frames convbin lost removed, the LLI rule set gives convbin's LLI exactly."""
    c = converted[stem]
    data = b"".join(ch for ch, _ in iter_chunks(c.src))
    index = index_frames(data)
    rawx = decode_rawx(data, index)
    block = rawx if rawx.frame.size else decode_raw(data, index)
    _, ref = rinex.read_obs3(c.ref_obs)
    ref_times = {e.time for e in ref if e.flag == 0}
    full = rinex.obs_from_rawx(block) if rawx.frame.size else rinex.obs_from_raw(block)
    keep_t = {
        t for t in full.t_gps_ns.tolist()
        if rinex_format.epoch_line(t, 0, 0, True, [])[2:29] in ref_times
    }
    keep = np.isin(block.gps_week * 604_800_000_000_000 + block.tow_ns, list(keep_t))
    sub = block.subset(keep)
    obs = rinex.obs_from_rawx(sub) if rawx.frame.size else rinex.obs_from_raw(sub)
    path = tmp_path / "sub.obs"
    rinex.write_obs(path, obs, [], rinex.HeaderInfo())
    _, ours = rinex.read_obs3(path)
    assert len([e for e in ours if e.flag == 0]) == len(ref_times)
    assert _compare(ours, ref, lli=True) == []


def _event_times(path: Path) -> list[int]:
    """Event epochs as 100 ns units of the day (text-exact)."""
    _, eps = rinex.read_obs3(path)
    out = []
    for e in eps:
        if e.flag == 5:
            y, mo, d, h, mi, s = e.time.split()
            out.append((int(h) * 3600 + int(mi) * 60) * 10**7 + round(float(s) * 1e7))
    return out


@pytest.mark.parametrize(
    ("stem", "ours_n", "convbin_n"),
    [("rover-20181104-1634", 598, 526), ("rover-20181009-1221", 589, 589),
     ("rover-20181004-1532", 318, 318), ("rover-20181004-1237", 4, 4)],
)
def test_event_epochs(
    converted: dict[str, Converted], stem: str, ours_n: int, convbin_n: int
) -> None:
    c = converted[stem]
    ours = _event_times(c.result.obs_path)
    ref = _event_times(c.ref_obs)
    assert (len(ours), len(ref), c.result.events) == (ours_n, convbin_n, ours_n)
    # Every convbin event is ours; RINEX keeps 100 ns and convbin rounds its double, so a
    # time exactly halfway between two 100 ns steps may land on either side.
    for t in ref:
        j = int(np.searchsorted(ours, t))
        near = [abs(ours[k] - t) for k in (j - 1, j) if 0 <= k < len(ours)]
        assert min(near) <= 1, t


def test_marks_equal_convbin_falling_edges_to_the_ns(
    converted: dict[str, Converted], shared_data: Path
) -> None:
    c = converted["rover-20181009-1221"]
    table = shared_data / "reference" / "timtm2_tables" / "rover-20181009-1221.timtm2.csv"
    with table.open() as f:
        rows = list(csv.reader(ln for ln in f if not ln.startswith("#")))
    head = rows[0]
    ref = [dict(zip(head, r, strict=True)) for r in rows[1:]]
    ref_ns = sorted(
        {int(r["fall_gpst_tow_s"].replace(".", "")) for r in ref if r["in_rtklib_rinex"] == "1"}
    )
    with c.result.marks_path.open() as f:
        marks = list(csv.DictReader(f))
    ours_ns = sorted(int(m["falling_gps_tow_s"].replace(".", "")) for m in marks)
    assert len(ref_ns) == 589
    assert ours_ns == ref_ns
    assert all(m["in_dropout"] in ("0", "1") for m in marks)


def test_marks_table_of_the_2hz_rover(converted: dict[str, Converted]) -> None:
    c = converted["rover-20181104-1634"]
    with c.result.marks_path.open() as f:
        marks = list(csv.DictReader(f))
    assert len(marks) == 598
    assert all(m["falling_utc"].endswith("Z") and m["time_base"] == "UTC" for m in marks)
    # Inside-dropout marks sit in gaps longer than 1.5 x the 0.5 s interval.
    gaps = [float(m["gap_s"]) for m in marks if m["in_dropout"] == "1"]
    assert gaps and min(gaps) > 0.75
    assert c.result.marks_in_dropout == len(gaps)


def _nav_records(path: Path) -> dict[tuple[str, str], list[float]]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        text = f.read().split("END OF HEADER")[1].splitlines()[1:]
    recs: dict[tuple[str, str], list[float]] = {}
    vals: list[float] = []
    for raw in text:
        ln = raw.replace("D", "E")
        if ln[:1].isalpha():  # a new record: keep GPS ones (SBAS and GLONASS are shorter)
            vals = [float(ln[23 + 19 * k : 42 + 19 * k]) for k in range(3)]
            if ln[0] == "G":
                recs[(ln[:3], ln[4:23])] = vals
            continue
        vals += [float(ln[4 + 19 * k : 23 + 19 * k]) for k in range(4)
                 if ln[4 + 19 * k : 23 + 19 * k].strip()]
    return recs


def test_navigation_equals_convbin(converted: dict[str, Converted]) -> None:
    c = converted["ubx_20080526"]
    ours = _nav_records(c.result.nav_path)
    ref = _nav_records(c.ref_nav)
    assert len(ours) == len(ref) == 18 == c.result.ephemerides
    assert ours.keys() == ref.keys()
    for key, rv in ref.items():
        ov = ours[key]
        # index 3+20: accuracy (RTKLIB writes its own URA table); 3+24: transmission time
        # (RTKLIB: HOW time; ours: start of subframe 1, 6 s earlier).
        for k, (a, b) in enumerate(zip(ov, rv, strict=True)):
            if k in (23, 27):
                continue
            assert math.isclose(a, b, rel_tol=1e-11, abs_tol=1e-20), (key, k, a, b)
        assert ov[27] == rv[27] - 6


def _rnx2rtkp(obs: Path, nav: Path, out: Path) -> np.ndarray:
    subprocess.run(
        ["rnx2rtkp", "-p", "0", "-sys", "G", "-o", str(out), str(obs), str(nav)],
        check=True, capture_output=True, timeout=120,
    )
    rows = [ln.split() for ln in out.read_text().splitlines() if not ln.startswith("%")]
    return np.array([[float(r[1]), float(r[2]), float(r[3]), float(r[4])] for r in rows])


needs_rtklib = pytest.mark.skipif(
    shutil.which("rnx2rtkp") is None,
    reason="RTKLIB rnx2rtkp not installed (apt-get install rtklib)",
)


@needs_rtklib
@pytest.mark.parametrize("stem", ["ubx_20080526", "rover-20181004-1237"])
def test_rnx2rtkp_same_single_point_solution(
    converted: dict[str, Converted], stem: str, tmp_path: Path
) -> None:
    c = converted[stem]
    ref_obs, ref_nav = tmp_path / "ref.obs", tmp_path / "ref.nav"
    ref_obs.write_bytes(gzip.decompress(c.ref_obs.read_bytes()))
    # Ours has GPS, GLONASS, Galileo and BeiDou ephemerides (not SBAS, QZSS): compare on those.
    head, body = gzip.decompress(c.ref_nav.read_bytes()).decode().split("END OF HEADER")
    keep, lines = False, []
    for ln in body.splitlines(keepends=True)[1:]:
        if ln[:1].isalpha():
            keep = ln[0] in "GREC"
        if keep:
            lines.append(ln)
    ref_nav.write_text(head + "END OF HEADER" + body.splitlines(keepends=True)[0] + "".join(lines))
    theirs = _rnx2rtkp(ref_obs, ref_nav, tmp_path / "ref.pos")
    # convbin writes no ionosphere parameters for the u-blox 8 logs (ours has subframe 4
    # page 18's): leave them out so both solutions use the same ionosphere model.
    nav = tmp_path / "ours.nav"
    nav.write_text("".join(
        ln for ln in c.result.nav_path.read_text().splitlines(keepends=True)
        if "IONOSPHERIC CORR" not in ln and "TIME SYSTEM CORR" not in ln
        or "IONOSPHERIC CORR" in ref_nav.read_text()
    ))
    ours = _rnx2rtkp(c.result.obs_path, nav, tmp_path / "ours.pos")
    assert len(ours) == len(theirs) > 100
    assert np.array_equal(ours[:, 0], theirs[:, 0])
    dlat_m = np.abs(ours[:, 1] - theirs[:, 1]) * 111_000
    dh_m = np.abs(ours[:, 3] - theirs[:, 3])
    assert dlat_m.max() < 0.001 and dh_m.max() < 0.001


@needs_rtklib
def test_aid_eph_nav_file_positions_the_neo6p(
    converted: dict[str, Converted], tmp_path: Path
) -> None:
    c = converted["6P-raw-PPP"]
    assert c.result.ephemerides >= 8 and not c.ref_nav.exists()
    sol = _rnx2rtkp(c.result.obs_path, c.result.nav_path, tmp_path / "p.pos")
    assert len(sol) > 200
    # The receiver's own fix (NAV-SOL) is the header's approximate position: single-point
    # solutions from our obs + AID-EPH nav must fall within a few tens of metres of it.
    from groundstation.geodesy import ecef_to_llh

    text = c.result.obs_path.read_text()
    line = next(ln for ln in text.splitlines() if "APPROX POSITION XYZ" in ln)
    lat, lon, h = ecef_to_llh(*(float(v) for v in line[:42].split()))
    assert np.median(np.abs(sol[:, 1] - lat)) * 111_000 < 30
    assert np.median(np.abs(sol[:, 3] - h)) < 60


def test_cli_writes_rinex_211(shared_data: Path, tmp_path: Path) -> None:
    src = shared_data / FILES["rover-20181004-1237"]
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "rinex", str(src), "-o", str(tmp_path),
         "--rinex", "2.11", "--marks", "mid", "--shutter-delay-ms", "1.5", "--marker", "ROVER",
         "--progress", "always"],
        capture_output=True, text=True, timeout=120, check=True,
    )
    assert "1205 epochs" in proc.stdout and "rinex:" in proc.stderr
    obs = (tmp_path / "rover-20181004-1237.obs").read_text()
    assert "     2.11           OBSERVATION DATA    M: Mixed" in obs
    assert obs.splitlines()[[i for i, ln in enumerate(obs.splitlines())
                             if "MARKER NAME" in ln][0]].startswith("ROVER")
    assert (tmp_path / "rover-20181004-1237.nav").exists()
    assert (tmp_path / "rover-20181004-1237.marks.csv").read_text().count("\n") == 5
    if shutil.which("rnx2rtkp"):
        sol = _rnx2rtkp(tmp_path / "rover-20181004-1237.obs",
                        tmp_path / "rover-20181004-1237.nav", tmp_path / "p.pos")
        assert len(sol) > 1000
