"""The command line of `marlin-temp job`: its action, options and help (the work is in `command`)."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated

import typer
from rich.console import Console

from ..common.connect import ConnectOptions
from ..common.options import error_console, run, with_connect_options

__all__ = ["JOB_HELP", "JobAction", "job"]

JOB_HELP = "\n\n".join(
    (
        "The print job of a printer that marlin-temp serve owns (--port serve:NAME): one job per printer, whoever "
        "started it (marlin-temp print, a slicer through the OctoPrint API, MQTT, a program).",
        "status (the default) says what it is, where it stands, who started it and the line to resume from; "
        "attach follows it until it ends (Ctrl-C leaves it running); pause, resume and cancel act on it as every "
        "door of the service does: a cancel stops feeding, lets the printer finish what it has, then runs the "
        "job's cancel script (by default every heater and the fan off). restart prints a paused job's file again "
        "from its first line, the heaters left on (OctoPrint's restart).",
        "Exit codes for status: 0 a job is known (running or ended), 3 none.",
    )
)


class JobAction(StrEnum):
    """What `marlin-temp job` does."""

    STATUS = "status"
    ATTACH = "attach"
    PAUSE = "pause"
    RESUME = "resume"
    RESTART = "restart"
    CANCEL = "cancel"


@with_connect_options()
def job(
    action: Annotated[JobAction, typer.Argument(help="What to do with the job.", case_sensitive=False)] = (
        JobAction.STATUS
    ),
    json_output: Annotated[bool, typer.Option("--json", help="Print the job as JSON (status and the others).")] = False,
    *,
    options: ConnectOptions,
) -> None:
    """Read, follow or steer a served printer's print job (the help text is `JOB_HELP`)."""
    from .command import run_job

    console = Console(highlight=False, emoji=False, soft_wrap=True)
    raise typer.Exit(int(run(run_job(options, action.value, json_output, console, error_console()))))
