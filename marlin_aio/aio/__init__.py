"""The asyncio side of marlin_aio: the `Printer` an application awaits (`printer`), the link that drives the
sans-I/O core on one port (`link`), opening ports (`_serial`), the handshake, the temperature feed, the poller,
prints in progress (`printhandle`) and G-code files read for printing (`gcodefile`).

An application needs only `marlin_aio`'s own names. Exported here: keeping a printer connected across unplugs,
halts and silences (`keep_connected`, with its `Backoff` and the `Retry` it reports), and, for tools that stream
files their own way, reading a G-code file as the printer will be fed it, checked whole first and watched for
changes while it prints. And the `WireLog` a `Printer` writes every line of its wire to (`wire_log=`).
"""

from typing import TYPE_CHECKING

from marlin_aio._lazy import lazy_exports

if TYPE_CHECKING:
    from marlin_aio.aio.gcodefile import file_lines, job_from_path, scan_gcode
    from marlin_aio.aio.reconnect import Backoff, Retry, keep_connected
    from marlin_aio.aio.wirelog import WireLog

#: Where each name lives: imported on its first use (`marlin_aio._lazy`).
_EXPORTS: dict[str, tuple[str, ...]] = {
    "marlin_aio.aio.gcodefile": ("file_lines", "job_from_path", "scan_gcode"),
    "marlin_aio.aio.reconnect": ("Backoff", "Retry", "keep_connected"),
    "marlin_aio.aio.wirelog": ("WireLog",),
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["Backoff", "Retry", "WireLog", "file_lines", "job_from_path", "keep_connected", "scan_gcode"]
