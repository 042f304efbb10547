"""What the live engine's inputs cost on the bus, and what the engine costs a core.

Run: python benchmarks/bench_obs.py [--duration S] [--seed N] [--repeat N]

A simulated LEA-6T flight (5 Hz, GPS L1) with its base is decoded as the daemon decodes it.
Reported, per second of flight:
- bytes on ``groundstation/<station>/obs`` (every epoch and subframe, compact) against the
  JSON ``epoch`` topic the same epochs would take (``bus.encode("epoch", ...)``);
- encoding time of the compact payloads against the JSON ones (same process, best of
  ``--repeat``): the daemon's added work;
- the live engine (``groundstation.live.rtk.LiveRtk``): time per rover epoch, as a share of
  one core at 5 Hz (each rover epoch solved with its base epoch, as live).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

from groundstation.bus import encode
from groundstation.live import obswire
from groundstation.live.rtk import BaseFeed, LiveRtk, measurements
from groundstation.records import RawEpoch, Subframe
from groundstation.sim.stream import SimConfig, simulate


def _best(fn: Callable[[], object], repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    sim = simulate(SimConfig(duration_s=a.duration, seed=a.seed))
    rover, base = measurements(sim.rover_bytes), measurements(sim.base_bytes)
    epochs = [r for r in rover if isinstance(r, RawEpoch)]
    frames = [r for r in rover if isinstance(r, Subframe)]

    def compact() -> int:
        return sum(len(obswire.encode_epoch(e)) for e in epochs) + sum(
            len(obswire.encode_subframe(f)) for f in frames)

    def as_json() -> int:
        return sum(len(encode("epoch", e, station="rover")) for e in epochs)

    n_compact, n_json = compact(), as_json()
    t_compact, t_json = _best(compact, a.repeat), _best(as_json, a.repeat)
    span = a.duration
    sats = sum(len(e.sats) for e in epochs) / len(epochs)
    print(f"flight {span:g} s, {len(epochs)} epochs ({sats:.1f} satellites each), "
          f"{len(frames)} subframes")
    print(f"obs (compact): {n_compact / span:,.0f} B/s; the JSON epoch topic: "
          f"{n_json / span:,.0f} B/s ({n_json / n_compact:.1f}x)")
    print(f"encoding: compact {t_compact / len(epochs) * 1e6:.1f} us/epoch, JSON "
          f"{t_json / len(epochs) * 1e6:.1f} us/epoch (compact/JSON {t_compact / t_json:.2f})")

    def engine() -> tuple[int, float]:
        eng = LiveRtk(tuple(sim.truth["base"]["ecef_m"]))
        feed = BaseFeed(eng, base)
        week = epochs[0].gps_week
        solved, spent = 0, 0.0
        for r in rover:
            if isinstance(r, Subframe):
                eng.add_subframe(r, week)
                continue
            feed.until(r.t_gps_ns, week)
            t0 = time.perf_counter()
            s = eng.add_rover(r)
            spent += time.perf_counter() - t0
            solved += s.quality != "none"
        return solved, spent

    solved, spent = engine()
    per = spent / max(solved, 1)
    print(f"live engine: {per * 1e3:.2f} ms per solved rover epoch ({solved}), "
          f"{per * 5 * 100:.1f} % of a core at 5 Hz")


if __name__ == "__main__":
    main()
