"""Whole-process wall time of ``groundstation rinex`` against RTKLIB ``convbin`` on the same input.

Both run as fresh processes on the same decompressed ``.ubx`` (convbin cannot read gzip), as a user
would run them; the best of N runs counts (the machine is shared, the minimum is the least noisy
estimate). convbin gets the options the reference RINEX was made with (``-od -os``: Doppler and
SNR); its progress output goes to /dev/null as ours does. Wall time and CPU time (user + system of
the process, from ``wait4``) are both reported: on a shared machine the CPU time is the steadier.

    .venv/bin/python benchmarks/bench_rinex.py [INPUT] [--runs 7]

A 10-hour simulated flight: ``groundstation simulate --out /tmp/sim10h.ubx --duration 36000
--faults default --seed 8``, then ``bench_rinex.py /tmp/sim10h.ubx --runs 3``.
"""

from __future__ import annotations

import sys

from bench_inspect import against_convbin


def main() -> int:
    return against_convbin(__doc__.splitlines()[0], "rinex", lambda _src, ubx, tmp: [
        "rinex", str(ubx), "-o", str(tmp / "gs"), "--progress", "never"])


if __name__ == "__main__":
    sys.exit(main())
