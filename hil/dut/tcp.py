"""What the TCP servers of ``hil dut serve`` (socketcand, Modbus TCP) share."""

from __future__ import annotations

import asyncio


async def close_handlers(handlers: dict) -> None:
    """Stopping: every open connection is closed and its handler left to finish (a handler
    cancelled by the loop's end would be reported as an error by asyncio's streams). A closed
    connection first sends what is buffered for it; one whose client reads nothing never would,
    so after ``FLUSH_S`` it is reset instead (it held a SIGTERM's exit for seconds)."""
    open_now = list(handlers.items())
    for _, writer in open_now:
        writer.close()
    if not open_now:
        return
    _, stuck = await asyncio.wait([task for task, _ in open_now], timeout=FLUSH_S)
    for task, writer in open_now:
        if task in stuck:
            writer.transport.abort()
    if stuck:
        await asyncio.wait(stuck, timeout=1.0)


#: how long a stopping server lets a connection send what is buffered for it
FLUSH_S = 0.2
