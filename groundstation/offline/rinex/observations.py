"""RXM-RAW / RXM-RAWX messages -> observations under RTKLIB demo5's u-blox rules (``ublox.c``).

Values, blanking and signal codes follow ``decode_rxmraw`` / ``decode_rxmrawx`` so that every
epoch convbin writes is reproduced value for value; the loss-of-lock indicator is the phase rule
of :mod:`groundstation.rules.phase` (the same the live decoder and the monitor use):

- RXM-RAW: values as sent, LLI from the receiver's ``lli`` byte.
- RXM-RAWX: pseudorange blank unless ``trkStat`` bit 0; phase blank unless the phase rule says
  it is usable; BeiDou GEO phase shifted by +0.5 cycle.

Unlike convbin, every signal keeps its own RINEX 3 code (``C2L`` and ``C2S``, ``C1C`` and
``C1B`` ...) instead of being merged into ``X`` codes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from groundstation import gpstime
from groundstation.rules import phase
from groundstation.ubx import layouts as L
from groundstation.ubx.fastraw import RawBlock, take_rows

SYSTEMS = "GRECJSI"
"""RINEX system letters, in the order systems are written."""
GNSS_LETTER = {0: "G", 1: "S", 2: "E", 3: "C", 5: "J", 6: "R"}
MAX_PRN = {"G": (1, 32), "S": (120, 158), "E": (1, 36), "C": (1, 63), "J": (1, 10), "R": (1, 27)}

SIGNAL_CODES: dict[tuple[int, int], str] = {
    (0, 0): "1C", (0, 3): "2L", (0, 4): "2S", (0, 6): "5I", (0, 7): "5Q",
    (1, 0): "1C",
    (2, 0): "1C", (2, 1): "1B", (2, 3): "5I", (2, 4): "5Q", (2, 5): "7I", (2, 6): "7Q",
    (3, 0): "2I", (3, 1): "2I", (3, 2): "7I", (3, 3): "7I", (3, 7): "5X",
    (5, 0): "1C", (5, 1): "1Z", (5, 4): "2S", (5, 5): "2L", (5, 8): "5I", (5, 9): "5Q",
    (6, 0): "1C", (6, 2): "2C",
}  # fmt: skip
"""RINEX 3.04 band+attribute for each u-blox (gnssId, sigId) of RXM-RAWX version 1."""
VERSION0_CODES = {0: "1C", 1: "1C", 2: "1X", 3: "2I", 5: "1C", 6: "1C"}
"""RXM-RAWX version 0 (u-blox 8) has no sigId: one L1-band signal per system."""
CODE_ORDER = ("1C", "1B", "1X", "1Z", "2C", "2L", "2S", "2I", "2X", "5I", "5Q", "5X", "7I", "7Q")
CODE_INDEX = {c: i for i, c in enumerate(CODE_ORDER)}
_CODE_NAMES = np.array(CODE_ORDER)
_CODE_TABLE_V1 = np.full((8, 16), -1, dtype=np.int64)
for (_g, _s), _c in SIGNAL_CODES.items():
    _CODE_TABLE_V1[_g, _s] = CODE_INDEX[_c]
_CODE_TABLE_V0 = np.full(8, -1, dtype=np.int64)
for _g, _c in VERSION0_CODES.items():
    _CODE_TABLE_V0[_g] = CODE_INDEX[_c]

@dataclass(frozen=True, slots=True)
class ObsSet:
    """Observations after the RTKLIB rules, one row per signal measurement, in stream order.

    Attributes:
        t_gps_ns: time of each epoch (GPS ns), one per message kept.
        leap_s: leap seconds each RXM-RAWX message declared valid (-1 where not).
        epoch: epoch row of each measurement.
        sys: RINEX system letter of each measurement (``"G"``, ``"R"`` ...).
        prn: RINEX satellite number (SBAS 120-158).
        code: RINEX 3 band+attribute (``"1C"``, ``"2L"`` ...).
        pr_m, cp_cyc, do_hz, cno_dbhz: values; 0.0 means blank (as in RTKLIB).
        lli: loss-of-lock indicator (bit 0 slip, bit 1 half cycle unresolved).
        glo_fcn: GLONASS frequency channel per slot.
        source: the message type the epochs came from.
    """

    t_gps_ns: npt.NDArray[np.int64]
    leap_s: npt.NDArray[np.int64]
    epoch: npt.NDArray[np.int64]
    sys: npt.NDArray[np.str_]
    prn: npt.NDArray[np.int64]
    code: npt.NDArray[np.str_]
    pr_m: npt.NDArray[np.float64]
    cp_cyc: npt.NDArray[np.float64]
    do_hz: npt.NDArray[np.float64]
    cno_dbhz: npt.NDArray[np.float64]
    lli: npt.NDArray[np.int64]
    glo_fcn: dict[int, int]
    source: str


def _empty_obs(source: str) -> ObsSet:
    z = np.zeros(0, dtype=np.int64)
    f = np.zeros(0, dtype=np.float64)
    s = np.zeros(0, dtype="<U2")
    return ObsSet(z, z, z, s, z, s, f, f, f, f, z, {}, source)


def obs_from_raw(block: RawBlock) -> ObsSet:
    """RXM-RAW (u-blox 4/5/6) messages → observations, as RTKLIB ``decode_rxmraw``."""
    h, m = block.header, block.meas
    keep_epoch = h["week"] != 0
    t = block.gps_week * gpstime.NS_PER_WEEK + block.tow_ns
    sv = m["sv"].astype(np.int64)
    is_sbas = sv >= 120
    ok = keep_epoch[block.epoch] & (((sv >= 1) & (sv <= 32)) | (is_sbas & (sv <= 158)))
    new_row = np.cumsum(keep_epoch) - 1
    m = take_rows(m, ok)
    sv = sv[ok]
    n = int(ok.sum())
    raw_lli = phase.raw_lli(sv, m["lli"].astype(np.int64), m["cpMes"].astype(np.float64))
    return ObsSet(
        t_gps_ns=t[keep_epoch],
        leap_s=np.full(int(keep_epoch.sum()), -1, dtype=np.int64),
        epoch=new_row[block.epoch[ok]],
        sys=np.where(sv >= 120, "S", "G"),
        prn=sv,
        code=np.full(n, "1C"),
        pr_m=m["prMes"].astype(np.float64),
        cp_cyc=m["cpMes"].astype(np.float64),
        do_hz=m["doMes"].astype(np.float64),
        cno_dbhz=np.floor(m["cno"].astype(np.float64) + 0.5),
        lli=raw_lli,
        glo_fcn={},
        source="RXM-RAW",
    )


def obs_from_rawx(block: RawBlock) -> ObsSet:
    """RXM-RAWX (u-blox 8/9/10) messages → observations, as RTKLIB ``decode_rxmrawx``."""
    h, m = block.header, block.meas
    if m.size == 0:
        return _empty_obs("RXM-RAWX")
    keep_epoch = h["week"] != 0
    gnss = m["gnssId"].astype(np.int64)
    sv = m["svId"].astype(np.int64)
    sig = m["sigId"].astype(np.int64)
    version = h["version"][block.epoch]
    letters = np.array([GNSS_LETTER.get(g, "") for g in range(8)])
    sysl = letters[np.minimum(gnss, 7)]
    prn = sv
    lo = np.array([MAX_PRN.get(s, (1, 0))[0] for s in letters.tolist()])
    hi = np.array([MAX_PRN.get(s, (1, 0))[1] for s in letters.tolist()])
    g7 = np.minimum(gnss, 7)
    sat_ok = (sysl != "") & (prn >= lo[g7]) & (prn <= hi[g7])
    code_i = np.where(
        version >= 1, _CODE_TABLE_V1[g7, np.minimum(sig, 15)], _CODE_TABLE_V0[g7]
    )
    ok = keep_epoch[block.epoch] & sat_ok & (code_i >= 0)
    idx = np.flatnonzero(ok)
    m = take_rows(m, idx)
    ep = block.epoch[idx]
    sysl, prn, gnss, sv = sysl[idx], prn[idx], gnss[idx], sv[idx]
    code_i = code_i[idx]
    code = _CODE_NAMES[code_i]
    trk = m["trkStat"].astype(np.int64)
    pr = np.where(trk & phase.TRK_PR_VALID, m["prMes"], 0.0)
    # Gen9 limit once any earlier message carried a second-band signal (RTKLIB's rcvtype).
    gen9_msg = np.zeros(h.size, dtype=bool)
    np.logical_or.at(gen9_msg, block.epoch, block.meas["sigId"] > 1)
    gen9_msg &= keep_epoch  # RTKLIB returns before looking at a week-0 message
    cp = m["cpMes"].astype(np.float64)
    valid, lli = phase.rawx_lli(
        (gnss * 256 + sv) * 64 + code_i, gnss, trk, m["locktime"].astype(np.int64), cp,
        m["cpStdev"].astype(np.int64), phase.rawx_gen9_before(gen9_msg)[ep],
    )
    cp = np.where(valid, cp, 0.0)
    bds_geo = (sysl == "C") & ((prn <= 5) | (prn >= 59)) & (cp != 0.0)
    cp = np.where(bds_geo, cp + 0.5, cp)
    new_row = np.cumsum(keep_epoch) - 1
    glo = sysl == "R"
    # (the last frequency number seen per slot wins, as in a dict built item by item)
    fcn = dict(zip(prn[glo].tolist(), (m["freqId"][glo].astype(np.int64) - 7).tolist(),
                   strict=True))
    leap = np.where(h["recStat"] & L.RAWX_REC_STAT.mask("leapSec"), h["leapS"].astype(np.int64), -1)
    return ObsSet(
        t_gps_ns=(block.gps_week * gpstime.NS_PER_WEEK + block.tow_ns)[keep_epoch],
        leap_s=leap[keep_epoch],
        epoch=new_row[ep],
        sys=sysl,
        prn=prn,
        code=code,
        pr_m=pr.astype(np.float64),
        cp_cyc=cp,
        do_hz=m["doMes"].astype(np.float64),
        cno_dbhz=m["cno"].astype(np.float64),
        lli=lli,
        glo_fcn=dict(sorted(fcn.items())),
        source="RXM-RAWX",
    )
