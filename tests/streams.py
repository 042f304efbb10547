"""Small UBX streams the tests build themselves: RXM-RAW epochs, TIM-TM2 marks, damage."""

from __future__ import annotations

import random

from groundstation.gpstime import NS_PER_WEEK
from groundstation.ubx import layouts as L

WEEK = 2300
TOW0_MS = 345_600_000



def rxm_raw(week: int, tow_ms: int, sats: list[tuple[int, int]],
            pr_offset_m: float = 0.0) -> bytes:
    """An RXM-RAW frame; ``sats`` are (prn, lli) with made-up but plausible values
    (``pr_offset_m``: another receiver's clock)."""
    rows = [
        {
            "cpMes": 110_000_000.125 + prn * 1000.5 + tow_ms / 1000.0,
            "prMes": 21_000_000.5 + prn * 100.25 + pr_offset_m,
            "doMes": -1234.5 + prn,
            "sv": prn,
            "mesQI": 7,
            "cno": 40 + prn % 10,
            "lli": lli,
        }
        for prn, lli in sats
    ]
    return L.RXM_RAW.frame(rows, iTOW=tow_ms, week=week)


def tim_tm2(
    count: int,
    week: int,
    falling_ms: int,
    falling_sub_ns: int,
    rising_ms: int | None,
    rising_sub_ns: int = 0,
    *,
    new_falling: bool = True,
    new_rising: bool = False,
    time_base: int = 1,
) -> bytes:
    """A TIM-TM2 frame as a LEA-6T in running mode with both edges would send it."""
    flags = L.TIM_TM2_FLAGS.compose(
        mode=1, run=1, timeBase=time_base, utc=1, time=1, newFallingEdge=int(new_falling),
        newRisingEdge=int(new_rising),
    )
    return L.TIM_TM2.frame(
        ch=0, flags=flags, count=count, wnR=week if rising_ms is not None else 0, wnF=week,
        towMsR=rising_ms or 0, towSubMsR=rising_sub_ns, towMsF=falling_ms,
        towSubMsF=falling_sub_ns, accEst=21,
    )


def flight_stream(
    n_epochs: int = 50, *, drop_epochs: set[int] | None = None, mark_every: int = 5,
    pr_offset_m: float = 0.0,
) -> tuple[bytes, list[bytes]]:
    """A 5 Hz stream of RXM-RAW epochs with a mark (falling, then rising 14 ms later) every
    ``mark_every`` epochs (``pr_offset_m``: as another receiver sees it, its clock elsewhere).
    Returns the stream and the list of its frames in order."""
    drop = drop_epochs or set()
    frames: list[bytes] = []
    count = 0
    for k in range(n_epochs):
        tow = TOW0_MS + 200 * k
        if k in drop:
            continue
        frames.append(rxm_raw(WEEK, tow, [(p, 0) for p in (3, 7, 11, 19, 23)], pr_offset_m))
        if k % mark_every == 2:
            fall_ms, fall_sub = tow + 57, 123_456
            frames.append(tim_tm2(count, WEEK, fall_ms, fall_sub, None))
            count += 1
            frames.append(
                tim_tm2(
                    count, WEEK, fall_ms, fall_sub, fall_ms + 14, fall_sub + 160_000,
                    new_falling=False, new_rising=True,
                )
            )
    return b"".join(frames), frames


def t_gps_ns(week: int, tow_ms: int, sub_ns: int = 0) -> int:
    return week * NS_PER_WEEK + tow_ms * 1_000_000 + sub_ns


def garbage(rng: random.Random, n: int) -> bytes:
    """Random bytes that cannot start a frame (no 0xB5), so they never form a valid one."""
    return bytes(rng.choice([b for b in range(256) if b != 0xB5]) for _ in range(n))


def epoch_with_mark(
    k: int, count: int | None, sats: list[tuple[int, int]], week: int = WEEK,
    tow0_ms: int = TOW0_MS,
) -> bytes:
    """Epoch ``k`` of a 5 Hz stream, followed by mark ``count`` (both edges in one TIM-TM2,
    falling 40 ms after the epoch, 14.16 ms pulse) when ``count`` is given."""
    tow = tow0_ms + 200 * k
    data = rxm_raw(week, tow, sats)
    if count is not None:
        data += tim_tm2(count, week, tow + 40, 1000 * k, tow + 54, 1000 * k + 160_000,
                        new_falling=True, new_rising=True)
    return data
