"""`marlin-temp serve`: one process owns the printers and keeps them connected; local clients share them over a
Unix socket (JSON-RPC 2.0, `marlin_aio.protocol.rpc`), and `marlin_aio.connect("serve:NAME")` is such a client
with `Printer`'s API. `verbs` is the table of what every door (the socket, MQTT, the OctoPrint API) may ask,
`server` is the service, `history` what it keeps for clients that join later,
`lifecycle` how it ends its prints and what it does after an end it did not choose (`journal`: its records)."""

from __future__ import annotations

from marlin_aio.aio.servicepaths import SOCKET_ENV, TOKEN_ENV, default_socket_path, service_holding
from marlin_aio.service.history import ConsoleLine, History
from marlin_aio.service.lifecycle import Lifecycle
from marlin_aio.service.server import (
    TOPICS,
    OctoPrintSettings,
    Service,
    ServiceRunningError,
    TcpSettings,
    check_private_folder,
)

__all__ = [
    "SOCKET_ENV",
    "TOKEN_ENV",
    "TOPICS",
    "ConsoleLine",
    "History",
    "Lifecycle",
    "OctoPrintSettings",
    "Service",
    "ServiceRunningError",
    "TcpSettings",
    "check_private_folder",
    "default_socket_path",
    "service_holding",
]
