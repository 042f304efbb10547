"""The README's test command, several times in a row, each while a CPU hog keeps every core busy.

Usage: ``.venv/bin/python benchmarks/suite_under_load.py [--runs 5] [--no-hog] [-- PYTEST ARGS]``

The hog is ``stress-ng --cpu N`` (Debian's ``stress-ng``) for the N cores, or a busy loop per
core when it is not installed. Each run prints its wall time, the suite's CPU time (user + sys
of pytest and everything it started), the load average before and after, and pytest's last
line, and the tests that failed (``--keep DIR``: a failed run's whole output); the script exits
1 if any run failed. It stops the hog it started, whatever happens.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BUSY_LOOP = "while True:\n    pass\n"


def start_hog(cores: int) -> list[subprocess.Popen[bytes]]:
    """``stress-ng --cpu cores``, or ``cores`` busy Python loops."""
    if shutil.which("stress-ng"):
        return [subprocess.Popen(["stress-ng", "--cpu", str(cores), "--quiet"],
                                 start_new_session=True)]
    return [subprocess.Popen([sys.executable, "-c", BUSY_LOOP], start_new_session=True)
            for _ in range(cores)]


def stop_hog(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=10)


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--no-hog", action="store_true", help="measure without the hog")
    parser.add_argument("--keep", default="", metavar="DIR",
                        help="write a failed run's whole pytest output into DIR")
    parser.add_argument("pytest_args", nargs="*", help="after --: more pytest arguments")
    args = parser.parse_args()
    cores = os.cpu_count() or 1
    failed = 0
    print(f"{args.runs} runs of .venv/bin/pytest -q -p no:cacheprovider on {cores} cores, "
          f"{'no hog' if args.no_hog else f'hog: {cores} busy processes'}")
    for run in range(1, args.runs + 1):
        hog = [] if args.no_hog else start_hog(cores)
        try:
            time.sleep(1.0)
            before = load()
            cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.monotonic()
            proc = subprocess.run([str(REPO / ".venv/bin/pytest"), "-q", "-p", "no:cacheprovider",
                                   *args.pytest_args], cwd=REPO, capture_output=True, text=True,
                                  check=False)
            wall = time.monotonic() - t0
            cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        finally:
            stop_hog(hog)
        cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
        lines = proc.stdout.strip().splitlines() or ["(no output)"]
        failed += proc.returncode != 0
        print(f"run {run}: {wall / 60:.1f} min ({wall:.0f} s), suite CPU {cpu:.0f} s, load "
              f"{before} -> {load()}, exit {proc.returncode}: {lines[-1]}", flush=True)
        # which tests failed, and pytest's whole output for a failed run (what the flake was)
        for ln in lines:
            if ln.startswith(("FAILED ", "ERROR ")):
                print(f"  {ln}", flush=True)
        if proc.returncode != 0 and args.keep:
            path = Path(args.keep) / f"run{run}.txt"
            path.write_text(proc.stdout + proc.stderr)
            print(f"  pytest's output: {path}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
