"""`marlin-temp farm`: many printers in one process, bridged to an MQTT broker.

The printers (`--port NAME=PORT`, `--config FILE`, `--sims N`) each run on their own supervisor (`marlin_aio.farm`), and
the bridge (`marlin_aio.farm.bridge`) publishes them to the broker. What happens is printed as one line per event on
stderr; a summary line when it stops. Secrets (the broker password) come from the environment or a file and are
never printed.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import time
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.markup import escape

from marlin_aio.aio import WireLog
from marlin_aio.farm.bridge import Bridge, BridgeSettings, BrokerSettings
from marlin_aio.farm.supervisor import FarmEvent, PrinterSpec
from marlin_aio.service import Lifecycle, Service, ServiceRunningError

from ..common.connect import UsageProblem
from ..serve.command import stop_prints

__all__ = ["PASSWORD_ENV", "FarmOptions", "broker_settings", "run_farm"]

#: The environment variable the broker password is read from (a secret never goes on the command line).
PASSWORD_ENV = "MARLIN_MQTT_PASSWORD"


@dataclass(frozen=True)
class FarmOptions:
    """How long to run (None: until Ctrl-C) and what to print."""

    duration_s: float | None = None
    quiet: bool = False
    socket: Path | None = None
    """Where the farm's printers are shared (`marlin-temp serve`'s socket; None: the default)."""
    wire_log: WireLog | None = None
    """Every printer's serial lines, each with the printer's name (--wire-log), or None."""


def broker_settings(
    broker: str,
    *,
    username: str | None,
    password_file: Path | None,
    client_id: str | None,
    tls_ca: Path | None,
    tls_cert: Path | None,
    tls_key: Path | None,
) -> BrokerSettings:
    """The broker to use, from `HOST[:PORT]` and the security options; the password from `--password-file` or the
    environment (`MARLIN_MQTT_PASSWORD`).

    Raises:
        UsageProblem: a bad address or port, a file that cannot be read, a key without a certificate.
    """
    host, sep, port_text = broker.rpartition(":")
    if not sep:
        host, port_text = broker, ""
    if not host:
        raise UsageProblem(f"--broker {broker!r}: give HOST or HOST:PORT")
    port = 8883 if (tls_ca or tls_cert) and not port_text else 1883
    if port_text:
        if not port_text.isdigit() or not 0 < int(port_text) < 65536:
            raise UsageProblem(f"--broker {broker!r}: the port must be a number from 1 to 65535")
        port = int(port_text)
    password = os.environ.get(PASSWORD_ENV) or None
    if password_file is not None:
        try:
            password = password_file.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise UsageProblem(f"--password-file {password_file}: {exc.strerror or exc}") from None
    if password is not None and username is None:
        raise UsageProblem(f"a broker password was given ({PASSWORD_ENV} or --password-file) but no --username")
    if tls_key is not None and tls_cert is None:
        raise UsageProblem("--tls-key needs --tls-cert (the client certificate it belongs to)")
    for option, path in (("--tls-ca", tls_ca), ("--tls-cert", tls_cert), ("--tls-key", tls_key)):
        if path is not None and not path.is_file():
            raise UsageProblem(f"{option} {path}: no such file")
    return BrokerSettings(
        host=host,
        port=port,
        username=username,
        password=password,
        client_id=client_id,
        tls_ca=str(tls_ca) if tls_ca else None,
        tls_cert=str(tls_cert) if tls_cert else None,
        tls_key=str(tls_key) if tls_key else None,
    )


async def run_farm(
    specs: list[PrinterSpec],
    broker: BrokerSettings,
    settings: BridgeSettings,
    options: FarmOptions,
    errors: Console,
) -> Bridge:
    """Run the farm and its bridge until `duration_s` passed or the task is cancelled; return the bridge (its
    counters say what was published)."""

    def show(event: FarmEvent) -> None:
        bridge.on_event(event)
        lifecycle.on_event(event)
        if not options.quiet:
            stamp = time.strftime("%H:%M:%S", time.localtime(event.time_s))
            errors.print(f"{stamp} {escape(event.printer)}: {escape(event.kind)}: {escape(event.message)}")

    # One supervisor: the farm is `marlin-temp serve` plus the bridge, so every command and program reaches its
    # printers through the socket too (`--port serve:NAME`), and a print is one print whoever started it.
    service = Service(specs, options.socket, on_event=show, presets=settings.presets)
    farm = service.farm
    farm.wire_log = options.wire_log
    bridge = Bridge(farm, broker, settings, owner=service)
    try:
        await service.check_socket()
    except ServiceRunningError as exc:
        raise UsageProblem(f"{exc}: the farm is a service itself; stop that one, or give --socket") from None
    # The service's life cycle, as `marlin-temp serve`'s: prints fed under a recorded bound, stopped with their
    # cancel script on SIGTERM, reported after a kill.
    lifecycle = Lifecycle(service)
    lifecycle.install()
    names = ", ".join(spec.name for spec in specs)
    if not options.quiet:
        errors.print(
            f"farm: {len(specs)} printer{'s' if len(specs) != 1 else ''} ({escape(names)}); publishing to "
            f"{escape(broker.address)} under {escape(settings.prefix)}/ at {settings.rate_hz:g} Hz; shared at "
            f"{escape(str(service.socket_path))} (--port serve:NAME); Ctrl-C stops",
            style="dim",
        )
    started = time.monotonic()
    # SIGTERM (systemd's stop) ends the farm as the end of --duration does: every printer and the bridge say
    # offline, the summary is printed, exit 0. Ctrl-C does the same and exits 130.
    stopped = asyncio.Event()
    loop = asyncio.get_running_loop()
    with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):  # not the main thread, or no signals
        loop.add_signal_handler(signal.SIGTERM, stopped.set)
    try:
        async with asyncio.timeout(options.duration_s), asyncio.TaskGroup() as group:
            running = [
                group.create_task(service.run(), name="farm"),
                group.create_task(bridge.run(), name="bridge"),
            ]
            await stopped.wait()
            await stop_prints(lifecycle, "SIGTERM", errors, [])
            for task in running:
                task.cancel()
    except TimeoutError:
        pass  # --duration is up: every printer and the broker connection were closed on the way out
    except BaseExceptionGroup as group_error:
        # The service or the bridge failed (a socket path too long, a folder not the user's): its one error, not
        # the task group's traceback.
        first = group_error.exceptions[0]
        while isinstance(first, BaseExceptionGroup):
            first = first.exceptions[0]
        raise first from None
    finally:
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.remove_signal_handler(signal.SIGTERM)
        if not options.quiet:
            errors.print(
                f"farm: stopped after {time.monotonic() - started:.0f} s; {bridge.published} messages published, "
                f"{bridge.telemetry_dropped} readings dropped, {bridge.events_lost} events lost",
                style="dim",
            )
    return bridge
