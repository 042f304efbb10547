"""CPU of the daemon's recording server under many one-byte chunk queries (issue 27, item 8).

A peer asks ``groundstation/<station>/q/recording/<session>`` for one byte at every other
offset of a served file, so no two ranges sent ever merge: the server's bookkeeping of what it
has sent (``live/serve.py``) then holds one range per query. The figure is the CPU time of the
server's query handler (``RecordingServer.answer``: parse, file read, bookkeeping), called in
this process as the Zenoh thread calls it; ``--zenoh`` sends the queries over a real Zenoh
session on loopback instead (both ends in this process, so its CPU includes the querier's).

    .venv/bin/python benchmarks/bench_serve_ranges.py [--queries 20000] [--order forward|reverse]
        [--zenoh]

Run it against another checkout with ``PYTHONPATH=/path/to/checkout`` (the package is
imported from the path, as installed otherwise).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=20_000)
    ap.add_argument("--order", choices=("forward", "reverse"), default="forward")
    ap.add_argument("--zenoh", action="store_true", help="real queries over loopback Zenoh")
    args = ap.parse_args()

    import groundstation
    from groundstation.live.serve import RecordingServer

    n = args.queries
    offsets = [2 * k for k in range(n)]
    if args.order == "reverse":
        offsets.reverse()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "st_20250602T080000Z.mcap"
        path.write_bytes(os.urandom(2 * n + 16))
        server = RecordingServer("st")
        sid = "st_20250602T080000Z-abcdef"
        assert server.add(path, sid) is not None
        query_key = f"groundstation/st/q/recording/{sid}"
        if args.zenoh:
            seconds = _over_zenoh(server, sid, path.name, offsets)
        else:
            t0 = time.process_time()
            for off in offsets:
                (reply,) = server.answer(query_key, {"file": path.name, "offset": str(off),
                                                     "length": "1"})
                assert not reply.error, reply.payload
            seconds = time.process_time() - t0
    print(f"groundstation from {Path(groundstation.__file__).parents[1]}")
    print(f"{n} one-byte queries ({args.order}, {'zenoh' if args.zenoh else 'in process'}): "
          f"{seconds:.3f} s CPU, {seconds / n * 1e6:.1f} us a query")


def _over_zenoh(server: object, sid: str, name: str, offsets: list[int]) -> float:
    import socket

    from groundstation.bus import open_bus
    from groundstation.config import ZenohSettings

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    endpoint = f"tcp/127.0.0.1:{port}"
    daemon = open_bus(ZenohSettings(listen=(endpoint,), connect=()))
    peer = open_bus(ZenohSettings(listen=(), connect=(endpoint,)))
    try:
        server.bind(daemon)  # type: ignore[attr-defined]
        time.sleep(1.0)  # the queryable declared and known to the peer
        t0 = time.process_time()
        for off in offsets:
            replies = peer.get(f"groundstation/st/q/recording/{sid}?file={name};offset={off};"
                               "length=1", timeout_s=10.0)
            assert replies, f"no reply at {off}"
        return time.process_time() - t0
    finally:
        peer.close()
        daemon.close()


if __name__ == "__main__":
    main()
