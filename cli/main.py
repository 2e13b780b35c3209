"""The `marlin-temp` command: watch, set and log the temperatures of a Marlin printer.

This is the typer app and the table of its commands. Each command's typer function lives with its family
(`watch/options.py`, `heaters/options.py`, ...), the options they share and the way they fail in
`common/options.py`. Typer has no async commands, so each command parses and checks its options, then calls
`asyncio.run` on an async function the tests can call too. Every failure ends as one line on stderr and an exit
code from `connect.Exit`; nothing is sent to the printer before the options are known to be good. The families'
heavy modules (the client's views, the simulator, the farm) are imported inside the functions, so
`marlin-temp --help` starts quickly.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Annotated, Any

import typer
from rich.markup import escape
from typer.core import TyperGroup

import marlin_aio

from .bench import options as bench
from .common.connect import EXIT_CODES_HELP
from .common.options import error_console
from .console import options as console
from .farm import options as farm
from .heaters import options as heaters
from .heaters import presets as heater_presets
from .job import options as job
from .keys import options as keys
from .logs import options as logs
from .ports import options as ports
from .printing import options as printing
from .serve import options as serve
from .watch import options as watch

__all__ = ["app"]


class _Commands(TyperGroup):
    """The command group, showing on/off options as bare flags in `--help` (typer lists `--sim <bool>` otherwise,
    which reads as if a value were needed)."""

    def get_params(self, ctx: Any) -> Any:
        params = super().get_params(ctx)
        for param in params:  # the group's own (--version, --help)
            if getattr(param, "is_flag", False) and getattr(param, "metavar", "") is None:
                param.metavar = ""
        return params

    def get_command(self, ctx: Any, cmd_name: str) -> Any:  # Any: click's types differ between typer releases
        return _bare_flags(ctx, super().get_command(ctx, cmd_name))

    def resolve_command(self, ctx: Any, args: Any) -> Any:
        """The command `args` call; one made on use (`_MADE_ON_USE`) in place of the stand-in that lists it."""
        name, command, rest = super().resolve_command(ctx, args)
        if name in _MADE_ON_USE:
            command = _bare_flags(ctx, _MADE_ON_USE[name]())
        return name, command, rest

    def main(
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        windows_expand_args: bool = True,
        **extra: Any,
    ) -> Any:
        """Run the command line; a usage error (a bad value, an unknown option) is one line on stderr, exit 2."""
        kwargs = {"args": args, "prog_name": prog_name, "complete_var": complete_var} | extra
        kwargs["windows_expand_args"] = windows_expand_args
        if not standalone_mode:
            return super().main(standalone_mode=False, **kwargs)
        try:
            outcome = super().main(standalone_mode=False, **kwargs)
        except _CLICK_EXCEPTION as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":
                exc.show()  # type: ignore[attr-defined]  # `marlin-temp` alone shows the help
            else:
                ctx = getattr(exc, "ctx", None)
                listed = "commands" if "No such command" in str(exc) else "options"
                where = f" ({ctx.command_path} --help lists the {listed})" if ctx is not None else ""
                message = exc.format_message()  # type: ignore[attr-defined]
                error_console().print(f"[bold red]error:[/] {escape(message)}{escape(where)}", markup=True)
            sys.exit(getattr(exc, "exit_code", 2))
        except typer.Abort:
            error_console().print("aborted")
            sys.exit(1)
        sys.exit(outcome if isinstance(outcome, int) else 0)


def _bare_flags(ctx: Any, command: Any) -> Any:
    if command is not None:
        for param in command.get_params(ctx):
            if getattr(param, "is_flag", False) and getattr(param, "metavar", "") is None:
                param.metavar = ""
    return command


#: Commands made when they are called, not at every start: `sim`'s options come from the simulator, whose import
#: costs the other commands a tenth of a second. `--help` lists a stand-in with the same help text.
_MADE_ON_USE = {"sim": ports.sim_command}

# typer 0.29 carries its own copy of click and older releases use click itself: its ClickException either way.
_CLICK_EXCEPTION: type[Exception] = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")


app = typer.Typer(
    cls=_Commands,
    name="marlin-temp",
    help="Watch, set and log the temperatures of a Marlin 3D printer. Try it with --sim: no printer needed.",
    epilog=EXIT_CODES_HELP,
    no_args_is_help=True,
    # -h as well as --help, on every command (sim's options are marlin-sim's, which has both).
    context_settings={"help_option_names": ["-h", "--help"]},
    add_completion=True,
    pretty_exceptions_enable=False,
)


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"marlin-temp {marlin_aio.__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version_callback, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    """Watch, set and log the temperatures of a Marlin 3D printer. Try it with --sim: no printer needed."""


# The commands, in the order `marlin-temp --help` lists them.
app.command("watch", help=watch.WATCH_HELP, epilog=EXIT_CODES_HELP)(watch.watch)
app.command("set", help=heaters.SET_HELP, epilog=EXIT_CODES_HELP)(heaters.set_targets)
app.command("presets", help=heater_presets.PRESETS_HELP, epilog=EXIT_CODES_HELP)(heater_presets.presets)
app.command("log", help=logs.LOG_HELP, epilog=EXIT_CODES_HELP)(logs.log)
app.command("print", help=printing.PRINT_HELP, epilog=EXIT_CODES_HELP)(printing.print_file)
app.command("job", help=job.JOB_HELP, epilog=EXIT_CODES_HELP)(job.job)
app.command("keys", help=keys.KEYS_HELP, epilog=EXIT_CODES_HELP)(keys.keys)
app.command("send", help=console.SEND_HELP, epilog=EXIT_CODES_HELP)(console.send)
app.command("terminal", help=console.TERMINAL_HELP, epilog=EXIT_CODES_HELP)(console.terminal)
app.command("serve", help=serve.SERVE_HELP, epilog=EXIT_CODES_HELP)(serve.serve)
app.command("farm", help=farm.FARM_HELP, epilog=EXIT_CODES_HELP)(farm.farm)
app.command("bench", help=bench.BENCH_HELP, epilog=EXIT_CODES_HELP)(bench.bench)
app.command("plot", epilog=EXIT_CODES_HELP)(logs.plot)
app.command("ports", help=ports.PORTS_HELP)(ports.ports)
app.command("sim", help=ports.SIM_HELP, epilog=ports.SIM_EPILOG)(ports.simulate)
