"""The socket's own verbs: saying hello, subscribing to a printer's feeds, and reading what it kept.

Only the socket's clients (the owner's Unix socket, TCP) have these: MQTT publishes its own topics and the
OctoPrint API is polled, so neither subscribes.
"""

from __future__ import annotations

from typing import Any

import marlin_aio
from marlin_aio.protocol.rpc import INVALID_PARAMS, RpcError
from marlin_aio.service.verbs.printer import info
from marlin_aio.service.verbs.table import (
    SOCKETS,
    SOCKETS_AND_HTTP,
    Access,
    Arg,
    Context,
    Encoded,
    Queue,
    Subscriber,
    verb,
)

__all__ = ["MAX_HISTORY_READINGS", "TOPICS"]

#: What a client can subscribe to.
TOPICS = frozenset({"readings", "console", "progress", "link", "requests"})
#: The most readings one `history` answer carries (evenly thinned past this): well inside a message's limit.
MAX_HISTORY_READINGS = 3_000


def _subscriber(context: Context) -> Subscriber:
    subscriber = context.caller.subscriber
    if subscriber is None:
        raise RpcError(INVALID_PARAMS, "only a client of the socket subscribes")
    return subscriber


def _subscribe(subscriber: Subscriber, printer: str, topics: object) -> list[str]:
    if not isinstance(topics, list) or not all(isinstance(t, str) for t in topics):
        raise RpcError(INVALID_PARAMS, f"topics are a list of names: {', '.join(sorted(TOPICS))}")
    unknown = set(topics) - TOPICS
    if unknown:
        raise RpcError(INVALID_PARAMS, f"no topic {sorted(unknown)[0][:40]!r}; there are {', '.join(sorted(TOPICS))}")
    subscriber.subscriptions.setdefault(printer, set()).update(topics)
    return sorted(subscriber.subscriptions[printer])


@verb(
    "hello",
    Arg("subscribe", list, [], "topics to subscribe to at once"),
    access=Access.READ,
    doors=SOCKETS,
    result="{service, printer, subscribed}",
)
async def hello(context: Context, args: dict[str, Any]) -> object:
    """A client's first word: the service and the printer it names, and its subscriptions taken."""
    farm_printer = context.farm_printer
    topics = args["subscribe"]
    subscribed = _subscribe(_subscriber(context), farm_printer.name, topics) if topics else []
    return {
        "service": {"version": marlin_aio.__version__, "printers": list(context.owner.farm.printers)},
        "printer": info(context.owner, farm_printer),
        "subscribed": subscribed,
    }


@verb("subscribe", Arg("topics", list, None, "topic names"), access=Access.READ, doors=SOCKETS, result="{subscribed}")
async def subscribe(context: Context, args: dict[str, Any]) -> object:
    """Be told of a printer's readings, console lines, job progress, link events or the firmware's requests."""
    return {"subscribed": _subscribe(_subscriber(context), context.farm_printer.name, args["topics"])}


@verb(
    "unsubscribe",
    Arg("topics", list, None, "topic names (none: all)"),
    access=Access.READ,
    doors=SOCKETS,
    result="{subscribed}",
)
async def unsubscribe(context: Context, args: dict[str, Any]) -> object:
    """Stop being told of some or all of a printer's topics."""
    subscriptions = _subscriber(context).subscriptions
    name = context.farm_printer.name
    topics = args["topics"]
    if topics is None:
        subscriptions.pop(name, None)
    else:
        subscriptions.get(name, set()).difference_update(topics)
    return {"subscribed": sorted(subscriptions.get(name, ()))}


@verb(
    "history",
    Arg("seconds", float, 300.0, "how far back"),
    access=Access.READ,
    queue=Queue.HEAVY,
    doors=SOCKETS_AND_HTTP,
    result="{readings, console}",
)
async def history(context: Context, args: dict[str, Any]) -> object:
    """The printer's readings of the last `seconds` (thinned to at most 3,000) and its recent console lines."""
    kept = context.owner.histories[context.farm_printer.name]
    # Evenly thinned, so any span fits one message (an hour at 10 Hz would not); made of each reading's and line's
    # JSON made once, so asking again and again costs the loop a join, not an encoding (`History`).
    readings = await kept.readings_json(float(args["seconds"]), MAX_HISTORY_READINGS)
    return Encoded(b'{"readings":' + readings + b',"console":' + await kept.console_json() + b"}")
