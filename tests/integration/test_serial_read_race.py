"""The serial source keeps a chunk read in the same loop iteration as its stall timer fires.

The source waits for the port's readiness under a ``stall_check_s`` timer. When the event loop
is busy (the live view drawing, a loaded laptop), the port's readiness and the timer's expiry
are handled in one loop iteration: the readiness callback has already read the chunk when the
timer cancels the wait. That chunk was dropped (the demo's "256 not read before the end", one
epoch more missing than the simulator injected); it must be delivered.
"""

from __future__ import annotations

import asyncio
import time

from groundstation.config import SerialSourceSettings
from groundstation.live.sources import SerialSource
from groundstation.sim.ptylink import PtyLink


def test_a_chunk_read_as_the_stall_timer_fires_is_delivered() -> None:
    pty = PtyLink()
    source = SerialSource(SerialSourceSettings(port=pty.path, stall_check_s=0.05),
                          on_event=lambda _event: None)
    payload = bytes(range(256))

    async def main() -> bytes:
        chunks = source.chunks()
        try:
            first: asyncio.Task[tuple[bytes, int]] = asyncio.ensure_future(anext(chunks))
            while not getattr(source.state, "connected", False):
                await asyncio.sleep(0.005)
            await asyncio.sleep(0.01)  # the source now waits for readiness, its timer running
            pty.write(payload)
            time.sleep(0.2)  # a busy loop: readiness and the expired timer in one iteration
            data, _ = await asyncio.wait_for(first, timeout=5.0)
            return data
        finally:
            await chunks.aclose()  # type: ignore[attr-defined]

    try:
        assert asyncio.run(main()) == payload
    finally:
        pty.close()
