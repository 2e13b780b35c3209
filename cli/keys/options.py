"""The command line of `marlin-temp keys`: its action, options and help (the work is in `command`)."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated

import typer
from rich.console import Console

from ..common.connect import ConnectOptions
from ..common.options import error_console, run, with_connect_options

__all__ = ["KEYS_HELP", "KeysAction", "keys"]

KEYS_HELP = "\n\n".join(
    (
        "The OctoPrint API's application keys of marlin-temp serve --octoprint (--port serve:NAME). An app (Home "
        "Assistant, a slicer) that asks for a key waits until you decide: the service prints the request and its "
        "token, and nothing is handed out without your approval.",
        "list (the default) shows the requests waiting and the keys issued; approve TOKEN issues a key, which the "
        "app then picks up by itself; deny TOKEN refuses; revoke KEY-START-or-APP takes keys back (the API refuses "
        "them from then on). Keys are kept in the service's private folder, beside its API key.",
        "Only the service's owner decides: these go through its Unix socket, never through TCP, MQTT or HTTP.",
    )
)


class KeysAction(StrEnum):
    """What `marlin-temp keys` does."""

    LIST = "list"
    APPROVE = "approve"
    DENY = "deny"
    REVOKE = "revoke"


@with_connect_options()
def keys(
    action: Annotated[KeysAction, typer.Argument(help="What to do.", case_sensitive=False)] = KeysAction.LIST,
    what: Annotated[
        str | None, typer.Argument(help="approve/deny: the request's token; revoke: a key's start or an app's name.")
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the service's answer as JSON.")] = False,
    *,
    options: ConnectOptions,
) -> None:
    """Decide the OctoPrint API's app-key requests (the help text is `KEYS_HELP`)."""
    from .command import run_keys

    console = Console(highlight=False, emoji=False, soft_wrap=True)
    raise typer.Exit(int(run(run_keys(options, action.value, what, json_output, console, error_console()))))
