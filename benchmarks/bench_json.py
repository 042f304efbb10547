"""JSON encoding of the records that travel: stdlib ``json`` against ``orjson`` and ``msgspec``.

Run: python benchmarks/bench_json.py [--input FILE] [--repeat N]

The payloads are real: RXM-RAWX epochs and TIM-TM2 marks decoded from a real rover log
(default: ``rover-20181009-1221.ubx.gz`` from ``../shared/data``), and the monitor's 1 Hz
``Status`` after it has seen that log. Each encoder turns the same records into the same JSON
(a leading ``type`` field as the recorder writes it, NaN and infinity as ``null``, tuples as
arrays); the script checks that every output decodes to the same object before timing. Figures
are per record, best of ``--repeat`` runs, and the speed-up over the stdlib path the project
used before (``plain_json`` + ``json.dumps``, the recorder's hot path).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import orjson

from groundstation import jsonio
from groundstation.live.monitor import Monitor
from groundstation.records import RawEpoch, Status, TimeMark
from groundstation.storage.reading import iter_chunks
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer

DEFAULT_INPUT = Path(__file__).resolve().parents[1] / (
    "../shared/data/real/jdesbonnet__GNSS_RTK_data/20181009/rover-20181009-1221.ubx.gz"
)


_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


def stdlib_plain(value: Any) -> Any:
    """The project's former stdlib path (the recorder's ``plain_json``: field names cached per
    class, NaN -> null), before ``json.dumps``; the hand-written code the libraries remove."""
    t = type(value)
    if t is int or t is str or t is bool or value is None:
        return value
    if t is float:
        return value if math.isfinite(value) else None
    if t is tuple or t is list:
        return [stdlib_plain(v) for v in value]
    names = _FIELD_NAMES.get(t)
    if names is None:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            names = _FIELD_NAMES[t] = tuple(f.name for f in dataclasses.fields(value))
        elif isinstance(value, dict):
            return {str(k): stdlib_plain(v) for k, v in value.items()}
        else:
            return value
    return {n: stdlib_plain(getattr(value, n)) for n in names}


def enc_stdlib(record: Any) -> bytes:
    body = {"type": type(record).__name__, **stdlib_plain(record)}
    return json.dumps(body, separators=(",", ":"), allow_nan=False).encode()


def enc_orjson(record: Any) -> bytes:
    # orjson writes NaN as null and dataclasses natively; the head is joined like jsonio does
    head = orjson.dumps({"type": type(record).__name__})
    return head[:-1] + b"," + orjson.dumps(record)[1:]


_MSGSPEC = msgspec.json.Encoder()


def enc_msgspec(record: Any) -> bytes:
    head = _MSGSPEC.encode({"type": type(record).__name__})
    return head[:-1] + b"," + _MSGSPEC.encode(record)[1:]


def enc_jsonio(record: Any) -> bytes:
    return jsonio.dumps_with({"type": type(record).__name__}, record)


ENCODERS: dict[str, Callable[[Any], bytes]] = {
    "stdlib json (plain_json + dumps)": enc_stdlib,
    "orjson": enc_orjson,
    "msgspec": enc_msgspec,
    "groundstation.jsonio (msgspec)": enc_jsonio,
}


def load_payloads(path: Path) -> dict[str, list[Any]]:
    framer, decoder, monitor = UbxFramer(), Decoder(), Monitor("bench")
    epochs: list[RawEpoch] = []
    marks: list[TimeMark] = []
    statuses: list[Status] = []
    now = time.time_ns()
    for data, _t_host in iter_chunks(path, chunk_bytes=4096):
        now += 100_000_000  # a plain log has no receive times: 10 reads a second
        for frame in framer.feed(data, now):
            rec = decoder.decode(frame)
            monitor.observe(rec, now)
            if isinstance(rec, RawEpoch):
                epochs.append(rec)
                # the monitor's 1 Hz status, as the daemon publishes and records it
                statuses.append(monitor.status(now))
            elif isinstance(rec, TimeMark):
                marks.append(rec)
    return {"status": statuses[-500:], "epoch": epochs[:500], "timemark": marks[:500]}


def _same(a: bytes, b: bytes) -> bool:
    return bool(json.loads(a) == json.loads(b))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--input", type=Path, default=DEFAULT_INPUT)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    if not args.input.exists():
        print(f"bench_json: {args.input}: not found (needs ../shared/data)", file=sys.stderr)
        return 2
    payloads = load_payloads(args.input)
    print(f"input {args.input.name}: " + ", ".join(f"{len(v)} {k}" for k, v in payloads.items()))
    for kind, records in payloads.items():
        ref = [enc_stdlib(r) for r in records]
        for name, enc in ENCODERS.items():
            if not all(_same(enc(r), x) for r, x in zip(records, ref, strict=True)):
                print(f"{kind}: {name} gives different JSON", file=sys.stderr)
                return 1
        sizes = sum(len(x) for x in ref) / len(ref)
        print(f"\n{kind}: {len(records)} records, {sizes:.0f} bytes each")
        best = dict.fromkeys(ENCODERS, math.inf)
        for _ in range(args.repeat):  # interleaved, so a busy moment hits every encoder alike
            for name, enc in ENCODERS.items():
                t0 = time.perf_counter()
                for r in records:
                    enc(r)
                best[name] = min(best[name], time.perf_counter() - t0)
        base = 0.0
        for name, t in best.items():
            per = t / len(records) * 1e6
            base = base or per
            print(f"  {name:<34} {per:8.2f} us/record  {base / per:6.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
