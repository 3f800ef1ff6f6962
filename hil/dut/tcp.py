"""What the TCP servers of ``hil dut serve`` (socketcand, Modbus TCP) share."""

from __future__ import annotations

import asyncio


async def close_handlers(handlers: dict) -> None:
    """Stopping: every open connection is closed and its handler left to finish (a handler
    cancelled by the loop's end would be reported as an error by asyncio's streams)."""
    for writer in list(handlers.values()):
        writer.close()
    if handlers:
        await asyncio.wait(list(handlers), timeout=2.0)
