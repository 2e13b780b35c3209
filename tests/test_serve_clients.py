"""Clients that misbehave against an in-process `Service` (the socket real, the printer simulated): one that never
reads loses its own notifications, counted, and never slows the printer or another client; one that piles up
requests without reading their answers is no longer read (the bound on what it holds is its own)."""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
from conftest import until

import marlin_aio
import marlin_aio.service.session as session_module
from marlin_aio.farm.supervisor import PrinterSpec
from marlin_aio.protocol import rpc
from marlin_aio.service import Service

QUEUE = 40


@contextlib.asynccontextmanager
async def service_at(path: Path) -> AsyncIterator[Service]:
    service = Service([PrinterSpec("sim", None, sim=True, sim_speed=50, poll_interval_s=0.01)], path)
    task = asyncio.create_task(service.run())
    try:
        await asyncio.wait_for(service.ready.wait(), 30)
        await until(lambda: service.farm.printers["sim"].link_up, "the printer connected")
        yield service
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def silent_client(
    service: Service, path: Path, request: bytes
) -> tuple[session_module.Session, asyncio.StreamWriter]:
    """A client that writes `request` and then never reads; its session's socket buffer made small, so what it
    does not read backs up into the service's queue within a few messages instead of after a kernel's worth."""
    before = set(service.sessions)
    reader, writer = await asyncio.open_unix_connection(str(path))
    writer.transport.pause_reading()  # type: ignore[attr-defined]  # reads nothing from here on (its kernel buffer fills, then the service's)
    writer.reader = reader  # type: ignore[attr-defined]  # held with the writer: a reader nobody holds discards
    writer.write(request)
    await until(lambda: bool(service.sessions - before), "the service to take the client")
    (session,) = service.sessions - before
    sock = session.writer.get_extra_info("socket")
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    return session, writer  # the caller holds the writer: a socket nobody holds is closed


async def test_a_client_that_never_reads_drops_its_own_notifications_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(session_module, "CLIENT_QUEUE_MESSAGES", QUEUE)
    path = tmp_path / "s.sock"
    async with service_at(path) as service:
        subscribe = rpc.request(1, "subscribe", {"printer": "sim", "topics": ["readings", "console"]})
        silent, held = await silent_client(service, path, rpc.encode_message(subscribe))
        async with marlin_aio.connect(f"serve:sim@{path}") as good:
            readings_before = service.farm.printers["sim"].readings
            # Each command adds console lines for the silent client too; the poller adds 100 readings a second.
            for number in range(60):
                assert (await good.send(f"M118 n{number}")).lines == (f"n{number}",)
            await until(lambda: silent.dropped > 0, "notifications to the silent client dropped")
            assert len(silent.queue) <= QUEUE
            await until(
                lambda: service.farm.printers["sim"].readings > readings_before + 50, "the poller going on meanwhile"
            )
            assert good.is_connected
            assert (await good.send("M118 last")).lines == ("last",)
        assert not silent.closing  # still connected: it only lost what it did not read
        held.close()


async def test_a_client_piling_up_unread_answers_is_no_longer_read(tmp_path: Path) -> None:
    path = tmp_path / "s.sock"
    async with service_at(path) as service, marlin_aio.connect(f"serve:sim@{path}") as good:
        # Answers are never dropped (each belongs to a request): a client that asks and asks and reads nothing is
        # no longer read once its unread answers pass the bound, so what it holds of the service stays bounded.
        history = rpc.encode_message(rpc.request(0, "history", {"printer": "sim", "seconds": 60}))
        flooder, held = await silent_client(service, path, history)
        flood = b"".join(rpc.encode_message(rpc.request(n, "history", {"printer": "sim"})) for n in range(1, 100))
        # The service's reader and the kernel take a few megabytes before the flooder's own writes back up.
        for _ in range(1_000):
            held.write(flood)
            await asyncio.sleep(0)  # lets the service's side take what it will; bounded by the loop's count
            if held.transport.get_write_buffer_size() > 0:
                break
        assert held.transport.get_write_buffer_size() > 0, "the service stopped reading the flooder"
        answered = flooder.answered
        assert flooder.unread_bytes <= session_module.UNREAD_BOUND_BYTES + rpc.MAX_MESSAGE_BYTES
        for number in range(20):
            assert (await good.send(f"M118 unbothered {number}")).lines == (f"unbothered {number}",)
        assert flooder.answered == answered, "nothing more is taken from it while it reads nothing"
        assert not flooder.closing  # still connected: it only waits for itself
        held.close()
