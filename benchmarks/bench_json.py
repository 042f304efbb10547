"""JSON encoding of the records that travel: stdlib ``json`` against ``orjson`` and ``msgspec``.

Run: python benchmarks/bench_json.py [--input FILE] [--repeat N]

The payloads are real: RXM-RAWX epochs and TIM-TM2 marks decoded from a real rover log
(default: ``rover-20181009-1221.ubx.gz`` from ``../shared/data``), and the monitor's 1 Hz
``Status`` after it has seen that log. Each encoder turns the same records into the same JSON
(NaN and infinity as ``null``, bytes as hex, tuples as arrays); the script checks that the
three outputs decode to equal objects before timing them. Figures are per record, best of
``--repeat`` runs, and as a ratio to the stdlib path the project used before
(``records.to_jsonable`` + ``json.dumps``).
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

from groundstation.live.monitor import Monitor
from groundstation.offline.readers import iter_chunks
from groundstation.records import RawEpoch, Status, TimeMark
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer

DEFAULT_INPUT = Path(__file__).resolve().parents[1] / (
    "../shared/data/real/jdesbonnet__GNSS_RTK_data/20181009/rover-20181009-1221.ubx.gz"
)


def stdlib_plain(value: Any) -> Any:
    """The stdlib path: convert to plain types (NaN -> null, bytes -> hex), then dumps."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: stdlib_plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value).hex()
    if isinstance(value, (tuple, list)):
        return [stdlib_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): stdlib_plain(v) for k, v in value.items()}
    return value


def enc_stdlib(record: Any) -> bytes:
    return json.dumps(stdlib_plain(record), separators=(",", ":"), allow_nan=False).encode()


def _hex(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value).hex()
    raise TypeError(type(value).__name__)


def enc_orjson(record: Any) -> bytes:
    return orjson.dumps(record, default=_hex, option=orjson.OPT_NON_STR_KEYS)


_MSGSPEC = msgspec.json.Encoder()


def enc_msgspec(record: Any) -> bytes:
    # msgspec writes bytes as base64 and has no hook for it: hex would need a conversion pass
    # first, so this measures its best case (the records timed here carry no bytes).
    return _MSGSPEC.encode(record)


ENCODERS: dict[str, Callable[[Any], bytes]] = {
    "stdlib json (to_jsonable + dumps)": enc_stdlib,
    "orjson (dataclasses natively)": enc_orjson,
    "msgspec (dataclasses natively)": enc_msgspec,
}


def load_payloads(path: Path) -> dict[str, list[Any]]:
    framer, decoder, monitor = UbxFramer(), Decoder(), Monitor("bench")
    epochs: list[RawEpoch] = []
    marks: list[TimeMark] = []
    statuses: list[Status] = []
    for data, t_host in iter_chunks(path, chunk_bytes=4096):
        for frame in framer.feed(data, t_host):
            rec = decoder.decode(frame)
            if isinstance(rec, RawEpoch):
                epochs.append(rec)
            elif isinstance(rec, TimeMark):
                marks.append(rec)
            now = getattr(rec, "t_host_ns", 0) or frame.t_host_ns
            monitor.observe(rec, now)
            status, _events = monitor.tick(now)
            if status is not None:
                statuses.append(status)
    if not statuses:
        statuses.append(monitor.status(time.time_ns()))
    return {"status": statuses[-200:], "epoch": epochs[:500], "timemark": marks[:500]}


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
        base = 0.0
        for name, enc in ENCODERS.items():
            best = math.inf
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                for r in records:
                    enc(r)
                best = min(best, time.perf_counter() - t0)
            per = best / len(records) * 1e6
            base = base or per
            print(f"  {name:<36} {per:8.2f} us/record  {base / per:6.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
