"""Valid-checksum frames with random field values of every decoded type, interleaved into a
simulated flight: live through a pty into ``groundstation run`` and offline through every
command that reads a recording (issue 27).

Run: python benchmarks/fuzz_valid_frames.py [--per-type 10000] [--flight-s 300] [--speed 1]
     [--seed 1] [--work DIR] [--no-ppk] [--timeout-s 900]

The flight is the demo's (``groundstation demo``: the default profile, its link faults: dropouts,
cut frames, garbage), ``--flight-s`` long. Into its byte stream, at frame boundaries (so every
frame the link delivered intact stays intact), go ``--per-type`` frames of each type the decoder
maps (:data:`fuzz_framer.DECODED_TYPES`) made by :func:`fuzz_framer.random_frame`: a third with
every field random, the rest what the receiver would send at that point of the flight with one
to three fields replaced by an extreme, NaN, infinite, random or shifted value (a time moved by
0.2 s up to a week, a week by up to 1024). The whole is written into a pty paced as the flight
(``--speed`` 1: the flight's own length), read by ``groundstation run`` (a real process: the
serial source, the recorder, the monitor, the Zenoh publisher on loopback), then the recording
goes through ``inspect``, ``rinex``, ``replay``, ``run --file`` and ``solve`` (the receiver's
positions, and PPK against the simulated base unless ``--no-ppk``).

Checked, or the script exits 1 naming what failed:

- live: the daemon runs for the whole flight and stops in order on SIGTERM (exit 0); no internal
  error and no traceback on stderr; its ``.ubx`` sidecar and the MCAP's ``/ubx/raw`` equal every
  byte sent; every time mark of the flight (the link's stream without the fuzz frames, decoded)
  was published on Zenoh (the subscriber's messages and the ``q/timemarks`` answer);
- offline: the decoder (streaming, as the daemon and inspect) and the bulk decoder (as rinex and
  the solver) keep and refuse the same epochs of the MCAP and of the sidecar
  (``rules/plausible``: one rule); every command exits 0 within ``--timeout-s``, without an
  internal error or a traceback, on the MCAP and on the sidecar.

It prints the frames sent per type, how many of them the daemon refused as implausible
(``rules/plausible``), the live and offline durations and the children's peak memory.
"""

from __future__ import annotations

import argparse
import bisect
import json
import os
import random
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fuzz_framer import DECODED_TYPES, Context, random_frame, stream_context

from groundstation.bus import decode, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.live.demo import DemoOptions, simulate_flight
from groundstation.offline.rinex.convert import read_frames
from groundstation.records import RawEpoch, TimeMark
from groundstation.sim.ptylink import PtyLink
from groundstation.sim.stream import SimResult
from groundstation.storage import iter_messages
from groundstation.storage.reading import Recording
from groundstation.ubx.decode import Decoder, message_name
from groundstation.ubx.fastraw import decode_raw, decode_rawx, plausible_epochs
from groundstation.ubx.framer import UbxFramer

REPO = Path(__file__).resolve().parents[1]
STATION = "fuzz"
MarkKey = tuple[int, int | None, int | None]
"""A time mark as compared: (count, falling edge GPS ns, rising edge GPS ns)."""


@dataclass
class Fuzzed:
    """The flight's stream with the fuzz frames in it."""

    chunks: list[tuple[int, bytes]]
    sent_per_type: Counter[str]
    real_marks: list[MarkKey]
    real_bytes: int


def fuzzed_stream(sim: SimResult, per_type: int, rng: random.Random) -> Fuzzed:
    """The link's timed chunks with ``per_type`` frames of every decoded type inserted before
    randomly chosen intact frames, each taking the time of the chunk it lands in."""
    data = sim.rover_bytes
    framer = UbxFramer()
    frames = framer.feed(data, 0) + framer.flush(0)
    starts = [f.offset for f in frames]
    contexts: list[Context] = []
    ctx = Context(0, 0)
    for f in frames:  # the context a frame is made in: the last RXM-RAW before the point
        contexts.append(ctx)
        ctx = stream_context(f.raw, ctx)
    dec = Decoder()
    real_marks = [(r.count, r.falling_t_gps_ns, r.rising_t_gps_ns)
                  for r in (dec.decode(f) for f in frames) if isinstance(r, TimeMark)]
    at: dict[int, list[bytes]] = {}
    sent: Counter[str] = Counter()
    for k in DECODED_TYPES:
        for _ in range(per_type):
            i = rng.randrange(len(starts))
            at.setdefault(starts[i], []).append(random_frame(k, rng, contexts[i]))
            sent[message_name(*k)] += 1
    cut = sorted(at)
    out: list[tuple[int, bytes]] = []
    pos = 0
    for t, chunk in sim.rover_chunks:
        end = pos + len(chunk)
        j = bisect.bisect_left(cut, pos)
        last = pos
        while j < len(cut) and cut[j] < end:
            if cut[j] > last:
                out.append((t, data[last : cut[j]]))
            out.append((t, b"".join(at[cut[j]])))
            last = cut[j]
            j += 1
        out.append((t, data[last:end]))
        pos = end
    return Fuzzed(out, sent, real_marks, len(data))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def env() -> dict[str, str]:
    e = {k: v for k, v in os.environ.items() if not k.startswith("GROUNDSTATION_")}
    e["PYTHONPATH"] = str(REPO)
    return e


@dataclass
class Report:
    failures: list[str] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)

    def check(self, ok: bool, what: str) -> None:
        self.lines.append(f"  {'ok  ' if ok else 'FAIL'} {what}")
        if not ok:
            self.failures.append(what)


def wait_for(path: Path, text: str, proc: subprocess.Popen[str], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if text in path.read_text(errors="replace"):
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.1)
    return False


def implausible_counts(summary: str) -> dict[str, int]:
    """The daemon's per-type implausible counts from its summary line."""
    for line in summary.splitlines():
        if "cannot belong to the session" in line:
            parts = line.split(":", 1)[1]
            return {p.rsplit(" ", 1)[0].strip(): int(p.rsplit(" ", 1)[1])
                    for p in parts.split(",") if p.strip()}
    return {}


def live(fz: Fuzzed, work: Path, speed: float | None, rep: Report) -> tuple[Path, Path, str]:
    """The stream through a pty into ``groundstation run``; returns its MCAP, sidecar, stdout."""
    out = work / "live"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    link = PtyLink()
    err_path = work / "run.stderr.txt"
    with err_path.open("w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "groundstation.cli", "run", "--port", link.path,
             "--station", STATION, "--out-dir", str(out), "--zenoh-listen", endpoint],
            cwd=work, env=env(), stdout=subprocess.PIPE, stderr=err, text=True)
    bus = None
    got: list[dict[str, Any]] = []
    lock = threading.Lock()
    try:
        if not wait_for(err_path, "publishing on Zenoh", proc, 60):
            rep.check(False, "the daemon started")
            raise SystemExit(1)
        bus = open_bus(ZenohSettings(listen=(), connect=(endpoint,)))

        def on_mark(_k: str, payload: bytes) -> None:
            with lock:
                got.append(decode(payload))

        bus.subscribe(key(STATION, "timemark"), on_mark)
        time.sleep(1.0)  # the subscription reaches the daemon
        t0 = time.monotonic()
        link.feed(fz.chunks, speed)
        fed_s = time.monotonic() - t0
        time.sleep(3.0)  # the daemon reads and publishes what is still in the pty
        alive = proc.poll() is None
        rep.check(alive, f"the daemon ran through the whole flight ({fed_s:.1f} s fed)")
        replies = bus.get(key(STATION, "q/timemarks"), timeout_s=10.0)
        queried = [decode(p) for _, p in replies]
        proc.send_signal(signal.SIGTERM)
        stdout, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if bus is not None:
            bus.close()
        link.close()
    stderr = err_path.read_text(errors="replace")
    rep.check(proc.returncode == 0, f"the daemon stopped in order on SIGTERM (exit "
                                    f"{proc.returncode})")
    rep.check("internal error" not in stderr and "Traceback" not in stderr,
              "no internal error, no traceback (live)")
    sent = b"".join(c for _, c in fz.chunks)
    mcaps, sidecars = sorted(out.glob("*.mcap")), sorted(out.glob("*.ubx"))
    rep.check(len(mcaps) == 1 and len(sidecars) == 1, "one MCAP and one sidecar")
    mcap, sidecar = mcaps[0], sidecars[0]
    rep.check(sidecar.read_bytes() == sent,
              f"sidecar equals the {len(sent):,} bytes sent ({sidecar.stat().st_size:,})")
    raw = b"".join(m.data for m in iter_messages(mcap, ["/ubx/raw"]))
    rep.check(raw == sent, "MCAP /ubx/raw equals the bytes sent")

    def keys(ms: list[dict[str, Any]]) -> Counter[MarkKey]:
        return Counter((int(m["count"]), m.get("falling_t_gps_ns"), m.get("rising_t_gps_ns"))
                       for m in ms)

    real = Counter(fz.real_marks)
    with lock:
        heard = keys(got)
    rep.check(not real - heard, f"all {sum(real.values())} time-mark records of the flight "
              f"on Zenoh ({sum(heard.values())} received, the rest plausible fuzz frames)")
    rep.check(not real - keys(queried), f"all of them in q/timemarks ({len(queried)} there)")
    counts = implausible_counts(stdout)
    rep.lines.append("  frames sent per type / refused as implausible by the daemon:")
    for name, n in sorted(fz.sent_per_type.items()):
        rep.lines.append(f"    {name:<11} {n:>7} / {counts.get(name, 0):>7}")
    (work / "run.stdout.txt").write_text(stdout)
    return mcap, sidecar, stdout


def same_verdicts(path: Path) -> tuple[int, int, int]:
    """The decoder's (streaming) and the bulk decoder's verdicts on every epoch of a recording:
    (epochs, kept, epochs they disagree on)."""
    frames, index = read_frames(path)
    _, _, times = plausible_epochs(index, decode_rawx(frames, index), decode_raw(frames, index))
    framer, dec = UbxFramer(), Decoder()
    seq: list[tuple[int, bool]] = []
    for chunk, t in Recording(path).chunks():
        for f in framer.feed(chunk, t):
            if f.key in ((0x02, 0x10), (0x02, 0x15)):
                seq.append((f.offset, isinstance(dec.decode(f), RawEpoch)))
    odd = set(dec.refuted_offsets)  # decoded, then found odd by the epochs after them
    kept = [ok and off not in odd for off, ok in seq]
    differ = sum(a != bool(b) for a, b in zip(kept, times.verdicts.ok.tolist(), strict=True))
    return len(seq), sum(kept), differ + abs(len(seq) - int(times.verdicts.ok.size))


def offline(mcap: Path, sidecar: Path, base: Path, base_xyz: str, work: Path, ppk: bool,
            timeout_s: float, rep: Report) -> None:
    for path in (mcap, sidecar):
        n, kept, differ = same_verdicts(path)
        rep.check(differ == 0, f"decoder and bulk decoder agree on all {n} epoch frames of the "
                               f"{path.suffix} ({kept} kept)")
    commands: list[tuple[str, list[str]]] = [
        ("inspect MCAP", ["inspect", str(mcap)]),
        ("inspect sidecar --json", ["inspect", "--json", str(sidecar)]),
        ("rinex MCAP", ["rinex", str(mcap), "-o", str(work / "rinex_mcap")]),
        ("rinex sidecar", ["rinex", str(sidecar), "-o", str(work / "rinex_ubx")]),
        ("replay MCAP", ["replay", str(mcap), "--no-zenoh"]),
        ("replay sidecar", ["replay", str(sidecar), "--no-zenoh"]),
        ("run --file sidecar", ["run", "--file", str(sidecar), "--no-zenoh", "--out-dir",
                                str(work / "run_file")]),
        ("solve (receiver)", ["solve", str(mcap), "--source", "receiver", "--out",
                              str(work / "solve_receiver"), "--no-progress"]),
    ]
    if ppk:
        commands.append(("solve (PPK, demo5)", [
            "solve", str(mcap), "--base", str(base), "--base-xyz", base_xyz, "--out",
            str(work / "solve_ppk"), "--no-progress"]))
    for name, argv in commands:
        t0 = time.monotonic()
        try:
            proc = subprocess.run([sys.executable, "-m", "groundstation.cli", *argv], cwd=work,
                                  env=env(), capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            rep.check(False, f"{name}: no answer within {timeout_s:g} s (a hang)")
            continue
        dt = time.monotonic() - t0
        clean = "internal error" not in proc.stderr and "Traceback" not in proc.stderr
        last = (proc.stderr.strip().splitlines() or [""])[-1][:120]
        rep.check(proc.returncode == 0 and clean,
                  f"{name}: exit {proc.returncode} in {dt:.1f} s"
                  + ("" if proc.returncode == 0 and clean else f" ({last})"))
        if name.startswith("inspect sidecar") and proc.returncode == 0:
            s = json.loads(proc.stdout)
            rep.lines.append(f"      epochs {s['epochs']}, implausible "
                             f"{sum(s['implausible'].values())}, time jumps {s['time_jumps']}")
        (work / f"{name.split()[0]}.{len(rep.lines)}.stderr.txt").write_text(proc.stderr)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-type", type=int, default=10_000)
    ap.add_argument("--flight-s", type=float, default=300.0, help="the demo flight's length")
    ap.add_argument("--speed", default="1", help="1 = the flight's own pace, N, or max")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--work", type=Path, default=None, help="keep the outputs here")
    ap.add_argument("--no-ppk", action="store_true", help="solve the receiver's positions only")
    ap.add_argument("--timeout-s", type=float, default=900.0, help="per offline command")
    args = ap.parse_args(argv)
    speed = None if args.speed == "max" else float(args.speed)
    rng = random.Random(args.seed)
    work = args.work or Path(tempfile.mkdtemp(prefix="fuzz-valid-frames-"))
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    sim = simulate_flight(DemoOptions(flight_s=args.flight_s, seed=args.seed))
    fz = fuzzed_stream(sim, args.per_type, rng)
    base = work / "base.ubx"
    base.write_bytes(sim.base_bytes)
    base_xyz = ",".join(f"{v:.4f}" for v in sim.truth["base"]["ecef_m"])
    sent = sum(len(c) for _, c in fz.chunks)
    print(f"flight {args.flight_s:g} s (seed {args.seed}): {fz.real_bytes:,} bytes of the link "
          f"+ {sum(fz.sent_per_type.values()):,} fuzz frames of {len(DECODED_TYPES)} types "
          f"= {sent:,} bytes in {len(fz.chunks):,} chunks; built in {time.monotonic() - t0:.1f} s")
    rep = Report()
    t1 = time.monotonic()
    mcap, sidecar, _ = live(fz, work, speed, rep)
    rep.lines.insert(0, f"live: groundstation run through a pty, {time.monotonic() - t1:.1f} s")
    t2 = time.monotonic()
    rep.lines.append("offline:")
    offline(mcap, sidecar, base, base_xyz, work, not args.no_ppk, args.timeout_s, rep)
    rep.lines.append(f"offline total {time.monotonic() - t2:.1f} s; children's peak RSS "
                     f"{resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024:.0f} MB")
    print("\n".join(rep.lines))
    print(f"work directory: {work}")
    if rep.failures:
        print(f"FAILED: {len(rep.failures)} check(s): " + "; ".join(rep.failures))
        return 1
    print("all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
