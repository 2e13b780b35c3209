"""Where `marlin-temp serve` listens, how a `serve:` port names one of its printers, and which ports it holds."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

__all__ = [
    "SERVE_PREFIX",
    "SOCKET_ENV",
    "TCP_PREFIX",
    "TOKEN_ENV",
    "default_socket_path",
    "parse_served_port",
    "service_holding",
]

#: A port that starts with this names a printer of `marlin-temp serve` (`serve:NAME`), not a device.
SERVE_PREFIX = "serve:"
#: `serve:NAME@tcp://HOST:PORT` names a service's TCP listener instead of its socket.
TCP_PREFIX = "tcp://"
#: The token a TCP client gives the service first (`marlin-temp serve --tcp` says where its token is).
TOKEN_ENV = "MARLIN_SERVE_TOKEN"

#: Names the service's socket instead of the default (`marlin-temp serve --socket` sets it for its children too).
SOCKET_ENV = "MARLIN_SERVE_SOCKET"


def default_socket_path() -> Path:
    """Where `marlin-temp serve` listens unless told otherwise: `$MARLIN_SERVE_SOCKET`, else
    `$XDG_RUNTIME_DIR/marlin-temp/serve.sock` (a per-user folder the system empties at logout), else
    `/tmp/marlin-temp-UID/serve.sock`."""
    named = os.environ.get(SOCKET_ENV)
    if named:
        return Path(named)
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    folder = Path(runtime) / "marlin-temp" if runtime else Path(tempfile.gettempdir()) / f"marlin-temp-{os.getuid()}"
    return folder / "serve.sock"


def parse_served_port(port: str) -> tuple[str | None, str]:
    """(printer name or None for the only one, where) of `serve:NAME`, `serve:NAME@/path.sock`,
    `serve:NAME@tcp://HOST:PORT`, `serve:/path.sock` or `serve:`: where is a socket's path or a `tcp://` URL.

    Raises:
        ValueError: `port` does not start with `serve:`.
    """
    if not port.startswith(SERVE_PREFIX):
        raise ValueError(f"not a served printer: {port!r} (expected serve:NAME)")
    rest = port[len(SERVE_PREFIX) :]
    if rest.startswith(("/", "tcp://")):
        return None, rest  # `serve:/path/to.sock`: the only printer of the service there
    name, at, path = rest.partition("@")
    return (name or None), (path if at else str(default_socket_path()))


def service_holding(port: str, socket_path: Path | None = None) -> str | None:
    """The `serve:NAME` URL of the printer that a running service holds on `port`, or None.

    Reads the service's registry (`serve.json` beside its socket) without connecting; a registry left by a
    service that is gone (its socket refuses) is not believed by whoever then connects.
    """
    path = (socket_path or default_socket_path()).with_name("serve.json")
    try:
        registry = json.loads(path.read_text())
        printers = registry["printers"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(printers, dict):
        return None
    pid = registry.get("pid")
    if not isinstance(pid, int) or not _alive(pid):
        return None  # left by a service that was killed: the port is free to open
    wanted = os.path.realpath(port) if port.startswith("/") else port
    for name, held in printers.items():
        if isinstance(held, str) and (held == port or (held.startswith("/") and os.path.realpath(held) == wanted)):
            suffix = "" if socket_path is None else f"@{socket_path}"
            return f"{SERVE_PREFIX}{name}{suffix}"
    return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process: alive
    return True
