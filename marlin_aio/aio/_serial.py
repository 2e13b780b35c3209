"""Opening the port: the only module that imports the serial packages.

Every way opening can fail becomes one `ConnectError` subclass with a sentence a user can act on, and a port that
goes away while open ends the link through `connection_lost` only (`_SerialTransport`): one `ConnectionLostError`,
no asyncio traceback beside it. A `memory://NAME` URL is the one kind pyserial does not open: it goes to
`memory.connect`, an in-process link to a listener in the same event loop (a simulator served with `serve_memory()`).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass

import serial
import serial_asyncio_fast

try:
    import termios
except ImportError:  # Windows: no termios, and no HUPCL to clear
    termios = None  # type: ignore[assignment]

from marlin_aio.aio import memory
from marlin_aio.errors import ConnectError, PortBusyError, PortNotFoundError, PortPermissionError

__all__ = ["PRINTER_BRIDGES", "PortInfo", "flush_input", "keep_dtr_on_close", "list_ports", "open_link"]

_log = logging.getLogger("marlin_aio")


def _is_url(port: str) -> bool:
    return "://" in port


async def open_link(
    port: str, baudrate: int, protocol_factory: Callable[[], asyncio.Protocol]
) -> tuple[asyncio.Transport, asyncio.Protocol]:
    """Open a device path or pyserial URL (`socket://host:port`, `rfc2217://...`) with an asyncio protocol; or a
    `memory://NAME` link to a listener in this event loop, where `baudrate` means nothing.

    Raises:
        PortNotFoundError: no such device, or nothing listening at the URL.
        PortBusyError: another program has the port open.
        PortPermissionError: access denied.
        ConnectError: any other failure to open.
    """
    if port.startswith(memory.SCHEME):
        return await memory.connect(port, protocol_factory)
    loop = asyncio.get_running_loop()
    kwargs: dict[str, object] = {"baudrate": baudrate}
    if not _is_url(port):
        # A second program on the same port would steal half the replies: lock it like a modem line.
        kwargs["exclusive"] = True
    try:
        if port.startswith("socket://"):
            # pyserial-asyncio-fast hands a socket:// URL to the loop's own socket transport, which already ends
            # quietly (connection_lost) when the peer goes away.
            return await serial_asyncio_fast.create_serial_connection(loop, protocol_factory, port, **kwargs)
        # What `create_serial_connection` does for every other port, with the transport that ends quietly.
        instance = await loop.run_in_executor(None, functools.partial(serial.serial_for_url, port, **kwargs))
    except (serial.SerialException, OSError, ValueError) as exc:
        raise _explain(port, baudrate, exc) from exc
    _write_without_spinning(instance)
    protocol = protocol_factory()
    transport = _SerialTransport(loop, protocol, instance)
    keep_dtr_on_close(transport)
    return transport, protocol


def _write_without_spinning(port: serial.SerialBase) -> None:
    """Make `port.write` return 0 when the port takes nothing now, as the transport expects of a non-blocking port.

    pyserial's own write, with the zero write timeout the transport sets, retries an EAGAIN at once and for ever:
    a port whose far end reads nothing (a device that only chatters, a flow-stopped line) filled its buffer and
    then held the event loop in that loop, so no timeout, Ctrl-C or SIGTERM could run again. A port without a
    file descriptor (an rfc2217:// URL) keeps its own write.
    """
    fd = getattr(port, "fd", None)
    if not isinstance(fd, int):
        return

    def write(data: bytes) -> int:
        try:
            return os.write(fd, data)
        except (BlockingIOError, InterruptedError):
            return 0  # the transport keeps the bytes and waits until the port can take them
        except OSError as exc:
            raise serial.SerialException(f"write failed: {exc}") from exc

    port.write = write  # this instance only: pyserial's class stays as it is


class _SerialTransport(serial_asyncio_fast.SerialTransport):
    """pyserial-asyncio-fast's transport, for which a port that went away is not a bug of the program.

    Its failed read already ends the link quietly (`connection_lost` with the error). Its failed write (a write that
    comes before the read that would have noticed: the pty's far end closed, the USB bridge was pulled) also went
    to the event loop's exception handler, which printed "Fatal write error on serial transport" and a traceback
    beside the library's own `ConnectionLostError`. Here such a write ends the link the way a failed read does.
    """

    def _fatal_error(self, exc: BaseException, message: str = "Fatal error on serial transport") -> None:
        if isinstance(exc, serial.SerialException | OSError):
            _log.debug("%s: %s", message, exc)
            self._abort(exc)
            return
        super()._fatal_error(exc, message)


def keep_dtr_on_close(transport: asyncio.Transport) -> bool:
    """Clear HUPCL on the port, so closing it leaves DTR raised; return True if it was a terminal that allowed it.

    Most Arduino-style boards reset when DTR rises, and the kernel raises it whenever the port is opened after a
    close that dropped it (HUPCL, the default). With HUPCL cleared, the next open finds DTR already up and the board
    keeps running, targets and all (what `stty -hupcl` does). The first open after plugging in still resets it: the
    line was down until then, and no setting made before open can change that on Linux.

    A `socket://` or `memory://` link has no modem lines: there it does nothing and returns False.
    """
    fd = getattr(transport.get_extra_info("serial"), "fd", None)
    if not isinstance(fd, int) or termios is None:
        return False  # a socket:// or memory:// link, or a platform without termios
    try:
        attributes = termios.tcgetattr(fd)
        if attributes[2] & termios.HUPCL:
            attributes[2] &= ~termios.HUPCL
            termios.tcsetattr(fd, termios.TCSANOW, attributes)
    except (termios.error, OSError):
        return False
    return True


def flush_input(transport: asyncio.Transport) -> None:
    """Throw away what the operating system has received but nobody has read yet (a serial port's input buffer).

    A TCP link has no such buffer to drop, nor has a memory link (its bytes wait for the loop's next turn, not in
    a buffer of the operating system); there, nothing happens.
    """
    port = transport.get_extra_info("serial")
    reset = getattr(port, "reset_input_buffer", None)
    if reset is not None and not isinstance(port, str):
        # A port that cannot flush has nothing worth flushing.
        with contextlib.suppress(serial.SerialException, OSError, NotImplementedError):
            reset()


def _explain(port: str, baudrate: int, exc: BaseException) -> ConnectError:
    code = getattr(exc, "errno", None)
    text = str(exc)
    if isinstance(exc, ConnectionRefusedError) or code == errno.ECONNREFUSED:
        return PortNotFoundError(f"nothing is listening at {port} (connection refused)")
    if code == errno.ENOENT or "No such file" in text:
        return PortNotFoundError(f"no such port: {port} (run 'marlin-temp ports' to list serial ports)")
    if code in (errno.EACCES, errno.EPERM) or "Permission denied" in text:
        return PortPermissionError(
            f"permission denied opening {port}: add your user to the 'dialout' group "
            "(sudo usermod -aG dialout $USER, then log in again)"
        )
    if code in (errno.EAGAIN, errno.EBUSY) or "exclusively lock" in text or "busy" in text.lower():
        return PortBusyError(f"{port} is in use by another program (close OctoPrint, Cura, screen, ...)")
    if isinstance(exc, ValueError):
        return ConnectError(f"cannot open {port} at {baudrate} baud: {text}")
    return ConnectError(f"cannot open {port}: {text}")


#: USB ids of the bridges printer boards use, with a name to show.
PRINTER_BRIDGES: dict[tuple[int, int], str] = {
    (0x1A86, 0x7523): "CH340",
    (0x10C4, 0xEA60): "CP2102",
    (0x0403, 0x6001): "FTDI",
    (0x0483, 0x5740): "STM32 VCP",
    (0x2341, 0x0042): "Arduino Mega 2560",
    (0x2341, 0x0010): "Arduino Mega 2560",
}


@dataclass(frozen=True, slots=True)
class PortInfo:
    """A serial port the system knows: its device path, description, USB id, and the bridge it looks like."""

    device: str
    description: str
    usb_id: str | None
    bridge: str | None

    @property
    def likely_printer(self) -> bool:
        """True when the USB id is one of the bridges printer boards use."""
        return self.bridge is not None


def list_ports() -> list[PortInfo]:
    """List the serial ports on this machine, printer-like bridges marked."""
    from serial.tools import list_ports as serial_list_ports

    found = []
    for port in sorted(serial_list_ports.comports(), key=lambda p: p.device):
        usb_id = None
        bridge = None
        if port.vid is not None and port.pid is not None:
            usb_id = f"{port.vid:04x}:{port.pid:04x}"
            bridge = PRINTER_BRIDGES.get((port.vid, port.pid))
        found.append(PortInfo(port.device, port.description or "", usb_id, bridge))
    return found
