"""The pipeline with a TCP source (as from str2str): exact bytes across a server restart."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from groundstation.config import RecorderSettings, Settings, TcpSourceSettings, ZenohSettings
from groundstation.live.daemon import run_daemon
from groundstation.storage import iter_messages, iter_raw_chunks, read_summary
from groundstation.ubx.build import build_frame


def test_tcp_source_reconnects_and_records_the_outage(tmp_path: Path) -> None:
    first = b"".join(build_frame(0x0A, 0x04, bytes([i]) * i) for i in range(60))
    second = b"".join(build_frame(0x0A, 0x04, bytes([i]) * 3) for i in range(40))

    async def main() -> Path:
        sent_first = asyncio.Event()

        async def serve_first(_r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
            w.write(first)
            await w.drain()
            w.close()  # the server goes away
            sent_first.set()

        server = await asyncio.start_server(serve_first, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        settings = Settings(
            source=TcpSourceSettings(host="127.0.0.1", port=port, reconnect_max_s=0.2),
            station="tcp", recorder=RecorderSettings(out_dir=tmp_path),
            zenoh=ZenohSettings(enabled=False),  # (the default endpoint is not this test's)
        )
        stop = asyncio.Event()
        files: list[Path] = []
        daemon = asyncio.create_task(run_daemon(settings, stop_event=stop, on_file=files.append))
        async with asyncio.timeout(10):
            await sent_first.wait()
            server.close()
            await server.wait_closed()
            await asyncio.sleep(0.5)  # refused connections in the meantime
            done = asyncio.Event()

            async def serve_second(_r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
                w.write(second)
                await w.drain()
                done.set()
                await asyncio.sleep(5)

            server2 = await asyncio.start_server(serve_second, "127.0.0.1", port)
            await done.wait()
            await asyncio.sleep(0.3)
            stop.set()
            summary = await daemon
            server2.close()
        assert summary.outages == 1 and summary.bytes_in == len(first) + len(second)
        return files[0]

    path = asyncio.run(main())
    assert b"".join(d for d, _ in iter_raw_chunks(path)) == first + second
    events = [json.loads(m.data) for m in iter_messages(path, ["/groundstation/event"])]
    (outage,) = [e for e in events if e["kind"] == "source.outage"]
    assert outage["data"]["duration_s"] > 0.4
    assert read_summary(path) is not None
