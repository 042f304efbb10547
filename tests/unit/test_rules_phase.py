"""The phase rule's two forms agree: streaming (decoder, monitor) and vectorised (RINEX) give the
same phase validity and LLI for every measurement, on random sequences and every real file."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from real_files import REAL_UBX_FILES, real_bytes

from groundstation.rules import phase
from groundstation.ubx.fastraw import RawBlock, decode_raw, decode_rawx, index_frames


def streaming_rawx(block: RawBlock) -> tuple[list[bool], list[int]]:
    rule = phase.RawxPhase()
    valid: list[bool] = []
    lli: list[int] = []
    m = block.meas
    for row in range(block.header.size):
        rows = np.flatnonzero(block.epoch == row)
        week0 = block.header["week"][row] == 0
        for i in rows.tolist():
            if week0:
                valid.append(False)
                lli.append(0)
                continue
            r = rule.measurement(
                (int(m["gnssId"][i]), int(m["svId"][i]), int(m["sigId"][i])),
                gnss=int(m["gnssId"][i]), trk_stat=int(m["trkStat"][i]),
                lock_ms=int(m["locktime"][i]), cp_cyc=float(m["cpMes"][i]),
                cp_stdev_idx=int(m["cpStdev"][i]),
            )
            valid.append(r.cp_valid)
            lli.append(r.lli)
        if not week0 and rows.size:
            rule.end_message(int(m["sigId"][rows].max()))
    return valid, lli


def vectorised_rawx(block: RawBlock) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int64]]:
    m = block.meas
    keep = block.header["week"][block.epoch] != 0
    gnss = m["gnssId"].astype(np.int64)
    key = (gnss * 256 + m["svId"]) * 64 + m["sigId"]
    second = np.zeros(block.header.size, dtype=bool)
    np.logical_or.at(second, block.epoch, m["sigId"] > 1)
    second &= block.header["week"] != 0
    valid = np.zeros(m.size, dtype=bool)
    lli = np.zeros(m.size, dtype=np.int64)
    v, ll = phase.rawx_lli(
        key[keep], gnss[keep], m["trkStat"][keep].astype(np.int64),
        m["locktime"][keep].astype(np.int64), m["cpMes"][keep].astype(np.float64),
        m["cpStdev"][keep].astype(np.int64), phase.rawx_gen9_before(second)[block.epoch][keep],
    )
    valid[keep], lli[keep] = v, ll
    return valid, lli


def streaming_raw(block: RawBlock) -> list[int]:
    rule = phase.RawPhase()
    m = block.meas
    out = []
    for i in range(m.size):
        if block.header["week"][block.epoch[i]] == 0:
            out.append(int(m["lli"][i]) & 3)
        else:
            out.append(rule.lli(int(m["sv"][i]), int(m["lli"][i]), float(m["cpMes"][i])))
    return out


def vectorised_raw(block: RawBlock) -> npt.NDArray[np.int64]:
    m = block.meas
    keep = block.header["week"][block.epoch] != 0
    out = m["lli"].astype(np.int64) & 3
    out[keep] = phase.raw_lli(
        m["sv"][keep].astype(np.int64), m["lli"][keep].astype(np.int64),
        m["cpMes"][keep].astype(np.float64),
    )
    return out


def assert_forms_agree(data: bytes) -> int:
    index = index_frames(data)
    rawx, raw = decode_rawx(data, index), decode_raw(data, index)
    v_s, l_s = streaming_rawx(rawx)
    v_v, l_v = vectorised_rawx(rawx)
    assert v_s == v_v.tolist()
    assert l_s == l_v.tolist()
    assert streaming_raw(raw) == vectorised_raw(raw).tolist()
    return int(np.count_nonzero(l_v)) + int(np.count_nonzero(vectorised_raw(raw)))


@pytest.mark.shared_data
@pytest.mark.parametrize("name", REAL_UBX_FILES)
def test_streaming_equals_vectorised_on_real_files(shared_data: Path, name: str) -> None:
    assert assert_forms_agree(real_bytes(shared_data, name)) > 0


def test_streaming_equals_vectorised_on_random_sequences() -> None:
    rng = random.Random(3)
    n = 4000
    gnss = np.array([rng.choice((0, 1, 2)) for _ in range(n)], dtype=np.int64)
    key = gnss * 10 + np.array([rng.randrange(3) for _ in range(n)])
    trk = np.array([rng.randrange(16) for _ in range(n)], dtype=np.int64)
    lock = np.array([rng.choice((0, 500, 9000, 20000, rng.randrange(60000))) for _ in range(n)])
    cp = np.array([rng.choice((0.0, -0.5, 1234.25, 99.5)) for _ in range(n)])
    cpstd = np.array([rng.randrange(16) for _ in range(n)], dtype=np.int64)
    gen9 = np.array([i > n // 2 for i in range(n)])
    valid, lli = phase.rawx_lli(key, gnss, trk, lock.astype(np.int64), cp, cpstd, gen9)
    rule = phase.RawxPhase()
    for i in range(n):
        rule.gen9 = bool(gen9[i])
        r = rule.measurement(int(key[i]), gnss=int(gnss[i]), trk_stat=int(trk[i]),
                             lock_ms=int(lock[i]), cp_cyc=float(cp[i]),
                             cp_stdev_idx=int(cpstd[i]))
        assert (r.cp_valid, r.lli) == (bool(valid[i]), int(lli[i])), i
    assert {0, 1, 2, 3} <= set(lli.tolist())


def test_slip_carried_over_blank_phase() -> None:
    """RXM-RAW: a slip flagged on a blank phase shows on the next valid phase, once."""
    rule = phase.RawPhase()
    got = [rule.lli(5, lli, cp) for lli, cp in ((0, 1.0), (1, 0.0), (0, 0.0), (0, 2.0), (0, 3.0))]
    assert got == [0, 1, 0, 1, 0]
    vec = phase.raw_lli(np.full(5, 5), np.array([0, 1, 0, 0, 0]), np.array([1.0, 0, 0, 2, 3]))
    assert vec.tolist() == got


def test_events_from_lli() -> None:
    assert phase.phase_events(1, False, new=True) == phase.PhaseEvents(False, False, False)
    assert phase.phase_events(3, False, new=False) == phase.PhaseEvents(True, True, False)
    assert phase.phase_events(0, True, new=False) == phase.PhaseEvents(False, False, True)
    assert phase.phase_events(2, True, new=True) == phase.PhaseEvents(False, True, False)
