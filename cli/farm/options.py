"""The command line of `marlin-temp farm`: its options and help, the printers and the broker checked before
`command` runs the bridge.

Its printers come from `--port NAME=PORT`, `--config FILE` and `--sims N` (`marlin_aio.farm.config`), each with
its own settings: the single-printer connect options (`common.options`) are not for it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Annotated

import typer

from ..common.connect import Exit, UsageProblem
from ..common.options import (
    BaudOption,
    FarmWireLogOption,
    SimSpeedOption,
    checked_wire_log,
    error_console,
    fail,
    run,
)
from ..common.presets import PresetsOption, load_presets_file
from ..common.printers import ConfigOption, IntervalOption, PortsOption, SimsOption, printer_specs

__all__ = ["FARM_HELP", "farm"]

FARM_HELP = (
    "Run many printers in one process and publish them to an MQTT broker, with Home Assistant discovery."
    "\n\n"
    "Give the printers as --port NAME=PORT (repeatable), --config FILE (TOML: a \\[defaults] table and "
    "\\[\\[printer]] tables with name, port, baud, poll_interval_s, max_hotend_celsius, ...), or --sims N for N "
    "simulated printers. Each printer reconnects on its own, with backoff, when it is unplugged, halts or does not "
    "answer; the others go on. The farm is marlin-temp serve plus the bridge: its printers are shared on serve's "
    "socket too (--socket), so every other command reaches them as --port serve:NAME."
    "\n\n"
    "Per printer NAME it publishes PREFIX/NAME/telemetry (each heater's actual, target and power in percent, at "
    "--rate), PREFIX/NAME/state (retained JSON), PREFIX/NAME/events (QoS 1, queued while the broker is away) and "
    "PREFIX/NAME/availability (retained); and PREFIX/bridge/availability with a Last Will, so a crashed bridge "
    'shows offline. With --allow-commands, {"action": "preset", "name": "PLA"} on PREFIX/NAME/command sets a '
    "preset of the presets file (marlin-temp presets lists them), and Home Assistant gets a button per preset. "
    "The broker password comes from $MARLIN_MQTT_PASSWORD or --password-file, never from the "
    "command line."
    "\n\n"
    "Try it: install Mosquitto (apt install mosquitto mosquitto-clients), run 'marlin-temp farm --sims 5', and "
    "watch with: mosquitto_sub -v -t 'marlin/#'"
)


def farm(
    ports: PortsOption = None,
    config: ConfigOption = None,
    sims: SimsOption = 0,
    sim_speed: SimSpeedOption = 1.0,
    baud: BaudOption = None,
    interval: IntervalOption = 0.1,
    broker: Annotated[str, typer.Option("--broker", help="MQTT broker as HOST[:PORT].")] = "127.0.0.1:1883",
    username: Annotated[str | None, typer.Option("--username", help="Broker user name.")] = None,
    password_file: Annotated[
        Path | None, typer.Option("--password-file", help="File with the broker password (or $MARLIN_MQTT_PASSWORD).")
    ] = None,
    client_id: Annotated[str | None, typer.Option("--client-id", help="MQTT client id (default: a random one).")] = (
        None
    ),
    tls_ca: Annotated[Path | None, typer.Option("--tls-ca", help="CA certificate: connect with TLS (port 8883).")] = (
        None
    ),
    tls_cert: Annotated[Path | None, typer.Option("--tls-cert", help="Client certificate for TLS.")] = None,
    tls_key: Annotated[Path | None, typer.Option("--tls-key", help="Client certificate's key.")] = None,
    prefix: Annotated[str, typer.Option("--prefix", help="Topic prefix.")] = "marlin",
    bridge_name: Annotated[
        str,
        typer.Option(
            "--bridge-name",
            help="The bridge's own topic level (PREFIX/NAME/availability); give each bridge sharing a broker and "
            "prefix its own.",
        ),
    ] = "bridge",
    rate: Annotated[
        float,
        typer.Option(
            "--rate",
            help="Telemetry messages per second and printer (at most the poll rate). The default, one every 5 s, "
            "keeps Home Assistant's recorder small; dashboards may want 1 or 2.",
        ),
    ] = 0.2,
    discovery: Annotated[
        bool, typer.Option("--discovery/--no-discovery", help="Publish Home Assistant MQTT discovery.")
    ] = True,
    discovery_prefix: Annotated[str, typer.Option("--discovery-prefix", help="Home Assistant's prefix.")] = (
        "homeassistant"
    ),
    allow_commands: Annotated[
        bool,
        typer.Option(
            "--allow-commands",
            help="Take commands on PREFIX/NAME/command (set targets, presets, G-code, prints, emergency stop); off "
            "by default.",
        ),
    ] = False,
    allowed_dir: Annotated[
        Path | None,
        typer.Option("--allowed-dir", help="With --allow-commands: prints may be started from files in this folder."),
    ] = None,
    socket: Annotated[
        Path | None,
        typer.Option(
            "--socket",
            help="Share the printers here as marlin-temp serve does (default: serve's), so every other command "
            "reaches them as --port serve:NAME.",
        ),
    ] = None,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds. Default: until Ctrl-C or SIGTERM.")
    ] = None,
    presets_file: PresetsOption = None,
    wire_log: FarmWireLogOption = None,
) -> None:
    """Bridge many printers to an MQTT broker (the help text is `FARM_HELP`)."""
    if importlib.util.find_spec("aiomqtt") is None:
        fail("marlin-temp farm needs aiomqtt, which is not installed: pip install 'marlin-aio[farm]'")
    from marlin_aio.farm.bridge import BridgeSettings

    from .command import FarmOptions, broker_settings, run_farm

    if duration is not None and not duration > 0:
        fail(f"--duration must be a positive number of seconds, got {duration:g}", Exit.USAGE)
    if not (rate > 0 and rate <= 1 / interval):
        fail(f"--rate must be above 0 and at most the poll rate ({1 / interval:g}/s), got {rate:g}", Exit.USAGE)
    for name, value in (("--prefix", prefix), ("--discovery-prefix", discovery_prefix)):
        if not value or any(c in value for c in "#+ ") or value.startswith("/") or value.endswith("/"):
            fail(f"{name} {value!r}: a topic prefix without '#', '+', spaces or a leading or trailing '/'", Exit.USAGE)
    from marlin_aio.farm.config import NAME_PATTERN, NAME_RULE

    if not NAME_PATTERN.fullmatch(bridge_name):
        fail(f"--bridge-name {bridge_name!r} must be {NAME_RULE}", Exit.USAGE)
    specs = printer_specs(ports, config, sims, baud=baud, interval_s=interval, sim_speed=sim_speed)
    try:
        broker_at = broker_settings(
            broker,
            username=username,
            password_file=password_file,
            client_id=client_id,
            tls_ca=tls_ca,
            tls_cert=tls_cert,
            tls_key=tls_key,
        )
    except UsageProblem as exc:
        fail(str(exc), exc.code)
    except ValueError as exc:
        fail(str(exc), Exit.USAGE)
    except OSError as exc:
        fail(f"{exc.filename or 'the password file'}: {exc.strerror or exc}", Exit.USAGE)
    if any(spec.name == bridge_name for spec in specs):
        fail(f"printer name {bridge_name!r} is the bridge's own (--bridge-name); choose another", Exit.USAGE)
    if allowed_dir is not None and not allow_commands:
        fail(f"--allowed-dir {allowed_dir} is for prints over MQTT: give --allow-commands too", Exit.USAGE)
    if allowed_dir is not None and not allowed_dir.is_dir():
        fail(f"--allowed-dir {allowed_dir}: no such folder", Exit.USAGE)
    settings = BridgeSettings(
        prefix=prefix,
        name=bridge_name,
        rate_hz=rate,
        discovery=discovery,
        discovery_prefix=discovery_prefix,
        allow_commands=allow_commands,
        allowed_dir=allowed_dir,
        # Only commands use the presets: without them a bad presets file need not stop the farm.
        presets=load_presets_file(presets_file).presets if allow_commands else (),
    )
    farm_options = FarmOptions(duration_s=duration, socket=socket, wire_log=checked_wire_log(wire_log))
    bridge = run(run_farm(specs, broker_at, settings, farm_options, error_console()))
    if bridge.connections == 0:
        fail(f"never reached the MQTT broker at {broker_at.address}: is it running (and the address right)?")
