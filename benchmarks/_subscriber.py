"""The farm benchmark's subscriber, in a process of its own: `python -m benchmarks._subscriber PORT OUTPUT`.

Subscribes to every printer's telemetry on the broker at 127.0.0.1:PORT and records, for each message, when it
arrived and the reading time its payload carries (both wall-clock seconds on this machine), until SIGTERM; then
writes them to OUTPUT as JSON and exits. It prints `ready` once subscribed.
"""

from __future__ import annotations

import asyncio
import json
import signal
import sys
import time

import aiomqtt


async def record(port: int) -> list[tuple[float, float]]:
    """(arrived, read) wall-clock times of every telemetry message until SIGTERM."""
    samples: list[tuple[float, float]] = []
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, stop.set)

    async def listen(client: aiomqtt.Client) -> None:
        async for message in client.messages:
            arrived = time.time()
            payload = message.payload if isinstance(message.payload, bytes) else str(message.payload).encode()
            samples.append((arrived, float(json.loads(payload)["time"])))

    async with aiomqtt.Client("127.0.0.1", port, identifier="benchmark-subscriber") as client:
        await client.subscribe("marlin/+/telemetry", qos=0)
        print("ready", flush=True)
        listener = asyncio.create_task(listen(client))
        await stop.wait()
        listener.cancel()
    return samples


if __name__ == "__main__":
    recorded = asyncio.run(record(int(sys.argv[1])))
    with open(sys.argv[2], "w") as file:
        json.dump(recorded, file)
