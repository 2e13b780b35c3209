"""The simulator's command-line options, defined once: `marlin-sim` builds its parser from them, and any other
command that serves the simulator (`marlin-temp sim`) makes its options of the same definition.

`SIMULATOR_OPTIONS` is the table: each row is one flag with its help text and the field it sets, in
`SimulatorConfig`, in `Faults`, or in how it is served (`SimulatorSettings`). Options of the printer and its
faults have no default of their own: an option not given leaves its field at the dataclass's default, so the
defaults live in one place. `simulator_settings()` turns the parsed options into the settings, and
`SimulatorSettings.server()` into a server ready to start.

argparse keeps this dependency-free and quick to start; `marlin-temp sim` makes typer options of the same rows,
with the same help (`option_help()`, which states the default) and `settings_from_values()`. So a new flag is a
row here (and its field): both commands list it, check it with its `parse` and pass it on.

Over 400 lines because the table is one list on purpose, one row an option: split, a flag could go missing from
one of the two command lines.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, NoReturn

from marlin_aio.simulator._config import Faults, SimulatorConfig
from marlin_aio.simulator._serve import SimulatorServer, serve_pty, serve_tcp

__all__ = [
    "DIALECT_SWITCHES",
    "GROUP_DESCRIPTIONS",
    "SIMULATOR_OPTIONS",
    "SimulatorOption",
    "SimulatorSettings",
    "add_simulator_options",
    "build_parser",
    "option_default",
    "option_help",
    "settings_from_values",
    "simulator_settings",
]


def _ratio(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, got {text}")
    return value


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def _not_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text}")
    return value


def _password(text: str) -> str:
    try:
        SimulatorConfig(password=text)  # the rule lives with the option it guards
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


@dataclass(frozen=True)
class SimulatorOption:
    """One command-line option: its flag, how its text is read, and the field its value sets."""

    flag: str
    """`--drop-ok`."""
    target: Literal["serve", "config", "faults"]
    """Where the value goes: `SimulatorSettings`, `SimulatorConfig` or `Faults`."""
    dest: str
    """The field it sets there (also the argparse `dest`)."""
    help: str
    parse: Callable[[str], object] | None = None
    """Reads the option's text (raising `argparse.ArgumentTypeError`); None for an on/off flag."""
    metavar: str | None = None
    choices: Sequence[int] | None = None
    negated: bool = False
    """An on/off flag that turns its field off (`--no-bed` sets `has_bed` to False)."""
    group: str | None = None
    """The help section it is listed in, if not the main one."""
    default: object = None
    """The value when not given; only for serve options (printer and fault fields keep their own default)."""
    aliases: tuple[str, ...] = ()
    """Older names still accepted, not listed in `--help` (scripts written for them keep working)."""


#: The on/off dialect switches of SimulatorConfig: each is a flag named after its field (`--bare-busy` sets
#: `bare_busy`), so adding one here is all it takes.
DIALECT_SWITCHES: tuple[tuple[str, str], ...] = (
    ("checksum_required", "refuse unnumbered lines: 'Error: Missing checksum', no ok, not run"),
    ("plain_wait_lines", "M109/M190/M191 wait lines without ' W:'"),
    ("bare_busy", "keepalives as 'busy:processing', without 'echo:'"),
    ("repetier_targets", "'TargetExtr0:200'-style target lines, reports without ' /target'"),
    ("m114_on_ok", "M114 answers on its ok line: 'ok X:.. Y:.. Z:.. E:.. Count ...'"),
)

_DIALECTS = "dialects"
#: What each help section (`SimulatorOption.group`) holds.
GROUP_DESCRIPTIONS = {_DIALECTS: "firmware variants and options a host meets in the field"}

#: Every option of `marlin-sim`, in the order `--help` lists them.
SIMULATOR_OPTIONS: tuple[SimulatorOption, ...] = (
    SimulatorOption(
        "--tcp",
        "serve",
        "tcp_port",
        "serve on TCP 127.0.0.1:PORT (0 picks a free port)",
        parse=int,
        metavar="PORT",
    ),
    SimulatorOption(
        "--host", "serve", "host", "TCP address to listen on (default %(default)s)", parse=str, default="127.0.0.1"
    ),
    SimulatorOption(
        "--sim-speed",
        "serve",
        "time_scale",
        "simulated seconds per real second (default 1); the same name as marlin-temp's --sim-speed",
        aliases=("--time-scale", "--speed"),
        parse=_positive,
        metavar="SPEED",
        default=1.0,
    ),
    SimulatorOption(
        "--baud",
        "serve",
        "baud_rate",
        "pace both directions like a UART at RATE bits/s, 10 bits a byte, in real time (default: unpaced)",
        parse=_positive_int,
        metavar="RATE",
    ),
    SimulatorOption(
        "--motion-time-scale",
        "config",
        "motion_time_scale",
        "factor on how long moves take; 0 makes them instant (default 1)",
        parse=_not_negative,
        metavar="FACTOR",
    ),
    SimulatorOption(
        "--command-time",
        "config",
        "command_time_s",
        "seconds Marlin's command loop takes over each command before it runs it and says ok (default 0.001, as"
        " Marlin 2.1 on an ATmega2560: about 1,000 short lines a second); 0 runs each at once",
        parse=_not_negative,
        metavar="SECONDS",
    ),
    SimulatorOption(
        "--report-time",
        "config",
        "report_time_s",
        "seconds an M105 takes instead (default 0.0043: with its answer on a 250000-baud wire, the 6.3 ms round"
        " trip measured on that board); 0 answers at once",
        parse=_not_negative,
        metavar="SECONDS",
    ),
    SimulatorOption(
        "--printers",
        "serve",
        "printers",
        "serve N independent printers, one URL per line on stdout (TCP: PORT, PORT+1, ... or N free ports)",
        parse=_positive_int,
        metavar="N",
        default=1,
        aliases=("--sims",),  # the name marlin-temp watch and farm give N simulated printers
    ),
    SimulatorOption(
        "--reset-on-open",
        "serve",
        "reset_on_open",
        "pty (Linux): reset and print the banner when a client opens the port, as DTR resets a board"
        " (not when it changes the settings of the open port; a TCP client always finds the board reset)",
        default=False,
    ),
    SimulatorOption(
        "--boot-delay",
        "config",
        "boot_delay_s",
        "simulated seconds a reset board spends in its bootloader, deaf and mute, before 'start' (default 0;"
        " real boards 1-3); a pty with --reset-on-open waits at least 0.05 s of real time",
        parse=_not_negative,
        metavar="SECONDS",
    ),
    SimulatorOption("--advanced-ok", "config", "advanced_ok", "ok N<line> P<planner> B<buffer> (ADVANCED_OK)"),
    SimulatorOption("--extruders", "config", "extruders", "hotends (1-8)", parse=int, metavar="N", choices=range(1, 9)),
    SimulatorOption("--chamber", "config", "has_chamber", "add a heated chamber (M141, C: in M105)"),
    SimulatorOption("--no-bed", "config", "has_bed", "no heated bed", negated=True),
    SimulatorOption(
        "--no-emergency-parser", "config", "emergency_parser", "M108/M112/M410 wait their turn", negated=True
    ),
    SimulatorOption("--rx-buffer", "config", "rx_buffer_size", "serial receive buffer", parse=int, metavar="BYTES"),
    SimulatorOption("--seed", "config", "seed", "seed for every random fault decision", parse=int, metavar="SEED"),
    SimulatorOption("--corrupt-rx", "faults", "corrupt_rx_ratio", "share of lines corrupted", _ratio, "RATIO"),
    SimulatorOption(
        "--flip-bits", "faults", "flip_bit_ratio", "share of received bytes with one bit flipped", _ratio, "RATIO"
    ),
    SimulatorOption("--drop-ok", "faults", "drop_ok_ratio", "share of oks not sent", _ratio, "RATIO"),
    SimulatorOption("--noise", "faults", "noise_ratio", "share of lines after noise", _ratio, "RATIO"),
    SimulatorOption(
        "--silent-after-lines",
        "faults",
        "silent_after_lines",
        "stall, answering nothing more, after running N numbered lines",
        parse=_positive_int,
        metavar="N",
    ),
    SimulatorOption(
        "--not-executed",
        "faults",
        "not_executed_ratio",
        "share of commands answered \"!! Lost communication with MCU 'mcu'\" and ok, and not run",
        parse=_ratio,
        metavar="RATIO",
    ),
    SimulatorOption(
        "--runout-at-line",
        "faults",
        "runout_at_line",
        "a filament runout just before numbered line N runs (a print's line N): the runout prompt,"
        " '//action:paused filament_runout 0', then M600 holds the line until the host answers (M876) or sends"
        " M108 (default: none)",
        parse=_positive_int,
        metavar="N",
    ),
    *(
        SimulatorOption("--" + name.replace("_", "-"), "config", name, help_text, group=_DIALECTS)
        for name, help_text in DIALECT_SWITCHES
    ),
    SimulatorOption(
        "--password",
        "config",
        "password",
        "PASSWORD_FEATURE: locked until 'M511 P<PASSWORD>' (again after every reset)",
        parse=_password,
        metavar="PASSWORD",
        group=_DIALECTS,
    ),
)


def option_default(option: SimulatorOption) -> object:
    """The value `option` has when it is not given: the table's for a serve option, else its field's default in
    `SimulatorConfig` or `Faults` (None for a field whose default means "off")."""
    if option.target == "serve":
        return option.default
    return getattr(SimulatorConfig() if option.target == "config" else Faults(), option.dest)


def option_help(option: SimulatorOption) -> str:
    """`option`'s help text as `marlin-sim --help` and `marlin-temp sim --help` show it: with its default, unless it
    is an on/off flag (off unless given), has none, or its text already says it."""
    default = option_default(option)
    text = option.help.replace("%(default)s", str(default))
    if option.parse is None or default is None or "default" in text:
        return text
    shown = f"{default:g}" if isinstance(default, float) else str(default)
    return f"{text} (default {shown})"


def add_simulator_options(parser: argparse.ArgumentParser) -> None:
    """Add every option of `SIMULATOR_OPTIONS` to `parser` (the dialects in a section of their own)."""
    groups: dict[str | None, argparse.ArgumentParser | argparse._ArgumentGroup] = {None: parser}
    for option in SIMULATOR_OPTIONS:
        if option.group is not None and option.group not in groups:
            groups[option.group] = parser.add_argument_group(option.group, GROUP_DESCRIPTIONS[option.group])
        # Printer and fault options not given stay out of the namespace, so their fields keep the default.
        default = option.default if option.target == "serve" else argparse.SUPPRESS
        # argparse formats help with %: the text is final already.
        arguments: dict[str, Any] = {
            "dest": option.dest,
            "default": default,
            "help": option_help(option).replace("%", "%%"),
        }
        if option.parse is None:
            arguments["action"] = "store_false" if option.negated else "store_true"
        else:
            arguments.update(type=option.parse, metavar=option.metavar)
            if option.choices is not None:
                arguments["choices"] = option.choices
        groups[option.group].add_argument(option.flag, **arguments)
        for alias in option.aliases:
            groups[option.group].add_argument(alias, **(arguments | {"help": argparse.SUPPRESS}))


class _OneLineErrors(argparse.ArgumentParser):
    """Bad input gets one line that says what is wrong (and where to look), not the whole usage."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (--help lists the options)\n")


def build_parser(prog: str = "marlin-sim") -> argparse.ArgumentParser:
    """The whole simulator command line as `prog` shows it."""
    parser = _OneLineErrors(
        prog=prog,
        description="Serve a simulated Marlin 2.1 printer. Prints the URL to open as the first line on stdout.",
    )
    add_simulator_options(parser)
    return parser


@dataclass(frozen=True)
class SimulatorSettings:
    """What a simulator command line asks for: the printer, its faults, and how it is served."""

    config: SimulatorConfig = field(default_factory=SimulatorConfig)
    faults: Faults = field(default_factory=Faults)
    tcp_port: int | None = None
    """Serve on this TCP port (0: any free one); None serves a pseudo-terminal."""
    host: str = "127.0.0.1"
    time_scale: float = 1.0
    baud_rate: int | None = None
    reset_on_open: bool = False
    printers: int = 1
    """How many independent printers to serve (each its own pty or port); see `servers()`."""

    def servers(self) -> list[SimulatorServer]:
        """One server per printer, none started yet. Printer `i` gets the seed `seed + i`, so their faults
        differ, and TCP port `tcp_port + i` unless the port is 0 (each then picks a free one)."""
        return [self.server(index) for index in range(self.printers)]

    def server(self, index: int = 0) -> SimulatorServer:
        """A server for these settings, not started yet (`async with settings.server() as server:`); `index`
        picks which printer of `printers` it is.

        Raises:
            ValueError: if `reset_on_open` is asked of TCP or off Linux.
        """
        config = self.config
        if index:
            config = dataclasses.replace(config, seed=config.seed + index)
        if self.tcp_port is not None:
            return serve_tcp(
                config,
                self.faults,
                host=self.host,
                port=self.tcp_port + index if self.tcp_port else 0,
                time_scale=self.time_scale,
                baud_rate=self.baud_rate,
            )
        return serve_pty(
            config,
            self.faults,
            time_scale=self.time_scale,
            baud_rate=self.baud_rate,
            reset_on_open=self.reset_on_open,
        )


def settings_from_values(values: Mapping[str, object]) -> SimulatorSettings:
    """The settings for the options in `values`, keyed by their `dest` and already read by their `parse` (a negated
    flag's value is its field's: False for `--no-bed`); an option left out keeps its default.

    Raises:
        ValueError: values the printer's configuration refuses together or alone (`SimulatorConfig`'s checks).
    """
    parts: dict[str, dict[str, Any]] = {"serve": {}, "config": {}, "faults": {}}
    for option in SIMULATOR_OPTIONS:
        if option.dest in values:
            parts[option.target][option.dest] = values[option.dest]
    try:
        return SimulatorSettings(SimulatorConfig(**parts["config"]), Faults(**parts["faults"]), **parts["serve"])
    except ValueError as exc:
        # The checks name the field ("rx_buffer_size must be at least 1"); the user typed the flag.
        message = str(exc)
        for option in SIMULATOR_OPTIONS:
            if option.dest in values and message.startswith(option.dest + " "):
                message = option.flag + message[len(option.dest) :]
        raise ValueError(message) from exc


def simulator_settings(arguments: argparse.Namespace) -> SimulatorSettings:
    """The settings that options parsed by a parser with `add_simulator_options()` ask for.

    Raises:
        ValueError: values the printer's configuration refuses (`settings_from_values`).
    """
    return settings_from_values(vars(arguments))
