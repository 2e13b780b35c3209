"""The service's table of verbs: every remote method, declared once, that every door of the service calls.

Moonraker's shape (`register_endpoint(path, request_type, handler, transports=...)`): a verb is one entry with its
name, its arguments' schema, who may call it (`Access`), how it is queued (`Queue`: an emergency stop goes at once,
a command waits its turn), the doors it is offered on, and what it returns. The doors are thin adapters that only
translate shapes: the socket's JSON-RPC (`marlin_aio.service.session`, and the served client through it, so the CLI
too), MQTT commands (`marlin_aio.farm.bridge`) and the OctoPrint HTTP API (`marlin_aio.service.octoprint`). So a
verb behaves the same whichever way it is called: a cancel runs the job's one cancel script from every door, a
target over the limit or for a heater the printer lacks is refused the same way from every door.

The verbs themselves are in `printer` (commands, temperatures, presets, prompts, the emergency stop, status),
`jobs` (uploads, the print job: start, pause, resume, cancel, status), `feeds` (subscriptions and history, the
socket's own) and `keys` (the OctoPrint API's app keys, the owner's socket's own). Adding a verb is one
`@verb(...)` entry beside its handler, and its tests.
"""

from marlin_aio.service.verbs import feeds, jobs, keys, printer  # the verbs register themselves as they are imported
from marlin_aio.service.verbs.table import (
    DOORS,
    NOT_HTTP,
    REQUIRED,
    SOCKETS,
    SOCKETS_AND_HTTP,
    VERBS,
    Access,
    Arg,
    Caller,
    Context,
    Door,
    Encoded,
    FarmOwner,
    Owner,
    Queue,
    Subscriber,
    Verb,
    call,
    heavy_verbs,
    printer_of,
    urgent_verbs,
    verb,
)

__all__ = [
    "DOORS",
    "NOT_HTTP",
    "REQUIRED",
    "SOCKETS",
    "SOCKETS_AND_HTTP",
    "VERBS",
    "Access",
    "Arg",
    "Caller",
    "Context",
    "Door",
    "Encoded",
    "FarmOwner",
    "Owner",
    "Queue",
    "Subscriber",
    "Verb",
    "call",
    "feeds",
    "heavy_verbs",
    "jobs",
    "keys",
    "printer",
    "printer_of",
    "urgent_verbs",
    "verb",
]
