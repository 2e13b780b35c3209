"""`marlin-temp keys`: list the app-key requests waiting and the keys issued, approve or deny a request, revoke keys;
through the service's own socket, which only its owner reaches."""

from __future__ import annotations

import json
import time
from typing import Any

from rich.console import Console
from rich.markup import escape

from ..common.connect import ConnectOptions, Exit, UsageProblem, open_printer

__all__ = ["run_keys"]


def _when(seconds: object) -> str:
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(float(seconds))) if isinstance(seconds, int | float) else "?"


async def run_keys(
    options: ConnectOptions, action: str, what: str | None, json_output: bool, console: Console, errors: Console
) -> Exit:
    """Do `action` (list, approve, deny, revoke) with `what` (a request's token, or a key's start or an app);
    return the exit code.

    Raises:
        UsageProblem: not a served printer, no such request or key, or `what` missing.
        MarlinError: the service failed.
    """
    if not (options.port or "").startswith("serve:"):
        raise UsageProblem("app keys are the service's: give --port serve:NAME (marlin-temp serve owns the printer)")
    if action != "list" and not what:
        what_to = "a key's first characters or an app's name" if action == "revoke" else "a request's token"
        raise UsageProblem(f"keys {action} needs what to {action}: {what_to} (keys list shows them)")
    async with open_printer(options, errors) as (printer, label):
        call = getattr(printer, "call", None)
        if call is None:
            raise UsageProblem(f"{label} is not a printer of marlin-temp serve")
        try:
            value: Any
            if action == "list":
                value = await call("keys")
            elif action == "revoke":
                value = await call("revoke_key", key=what)
            else:
                value = await call(f"{action}_key", token=what)
        except ValueError as exc:  # the service's INVALID_PARAMS: no such request or key
            raise UsageProblem(str(exc)) from None
    if json_output:
        console.print(json.dumps(value), markup=False)  # an app's name is the app's to choose
        return Exit.OK
    if action == "list":
        if not value["pending"] and not value["issued"]:
            console.print("no app has asked for a key, and none holds one")
        for request in value["pending"]:
            user = f" (user {request['user']})" if request["user"] else ""
            console.print(
                f"waiting: {escape(request['app'])}{escape(user)}: marlin-temp keys approve {request['token']} "
                f"(or deny)"
            )
        for key in value["issued"]:
            user = f" (user {key['user']})" if key["user"] else ""
            console.print(f"issued: {escape(key['app'])}{escape(user)}, key {key['key']}, {_when(key['issued'])}")
    elif action == "revoke":
        for key in value["revoked"]:
            console.print(f"revoked: {escape(key['app'])}, key {key['key']}")
    else:
        done = "approved: it gets its key at its next poll" if value["approved"] else "denied"
        console.print(f"{escape(value['app'])}: {done}")
    return Exit.OK
