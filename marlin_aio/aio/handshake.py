"""Starting a session: let the boot banner pass, synchronise, set the line counter, ask who the printer is.

Each step has the link's timeout and fails with `HandshakeError` naming the step; when the printer said something
but never answered, the error quotes it. The whole sequence has a bound of its own too (`HANDSHAKE_TIMEOUTS` link
timeouts): a port that keeps talking (garbage, stray `ok` lines, busy keepalives that restart a command's clock)
could otherwise keep a step's command alive for ever, and a user's `--timeout` would mean nothing.

Locked printers (PASSWORD_FEATURE) are unlocked with the password given, and a firmware that runs only numbered
lines is synchronised with the one numbered line it always takes (M110).
"""

from __future__ import annotations

import asyncio

from marlin_aio.aio.link import Link
from marlin_aio.errors import (
    ChecksumRequiredError,
    CommandTimeoutError,
    HandshakeError,
    HandshakeTimeoutError,
    LostReplyError,
    PrinterHaltedError,
    PrinterLockedError,
    PrinterResetError,
)
from marlin_aio.protocol.secrets import redact

__all__ = ["BAUD_RATES", "HANDSHAKE_TIMEOUTS", "handshake", "handshake_bound_s", "send_until_processed"]

#: The rates Marlin boards use, the usual first: a host that does not know tries them in this order (and a
#: handshake that met garbage names the others).
BAUD_RATES = (250_000, 115_200)

#: The handshake as a whole ends within this many link timeouts, whatever the port sends. A printer needs about
#: one for its boot banner and a moment for the rest; a noisy link may need a few more for the M110 (see
#: `M110_ATTEMPTS`), which is why it is not two.
HANDSHAKE_TIMEOUTS = 4


def handshake_bound_s(timeout_s: float) -> float:
    """How long `handshake` may take at most with the link timeout `timeout_s`, in seconds."""
    return HANDSHAKE_TIMEOUTS * timeout_s


async def handshake(link: Link, *, timeout_s: float, boot_quiet_s: float, password: str | None) -> bool:
    """Run the start-up sequence on a freshly opened `link`; return True if the board reset as the port opened
    (it printed `start`, its boot banner): whatever was set on it before (targets, fan) is gone.

    It ends within `handshake_bound_s(timeout_s)` whatever the port sends.

    Raises:
        HandshakeError: the printer did not answer a step (`HandshakeTimeoutError`, also when the whole sequence
            outlasted its bound), or it is halted.
        PrinterLockedError: the printer is locked and no (or a wrong) password was given.
    """
    steps = ["boot"]
    bound_s = handshake_bound_s(timeout_s)
    try:
        async with asyncio.timeout(bound_s) as scope:
            return await _run_steps(link, steps, timeout_s=timeout_s, boot_quiet_s=boot_quiet_s, password=password)
    except TimeoutError as exc:
        # A step's own HandshakeTimeoutError is a TimeoutError too: only the expiry of the bound is reworded here.
        if not scope.expired() or isinstance(exc, HandshakeError):
            raise
        raise HandshakeTimeoutError(_chatter_explanation(link, bound_s, steps[-1]), step=steps[-1]) from None
    finally:
        link.line_seen = None


async def _run_steps(
    link: Link, steps: list[str], *, timeout_s: float, boot_quiet_s: float, password: str | None
) -> bool:
    """The steps of `handshake`, each appended to `steps` as it begins (so the bound's error can name it)."""
    now = link.now
    # Set by every read while the banner passes; dropped afterwards so reads stop paying for it.
    line_seen = link.line_seen = asyncio.Event()
    # 1. Let the boot banner pass: many boards reset when the port opens and print for a moment. Wait until the
    #    line stream has been quiet for a short while; a board that does not reset prints nothing.
    boot_deadline = now() + timeout_s
    while now() < boot_deadline:
        line_seen.clear()
        try:
            await asyncio.wait_for(line_seen.wait(), boot_quiet_s)
        except TimeoutError:
            break
    link.line_seen = None
    # Whatever is left of the banner (half a line, noise from the reset) must not prefix the first reply.
    link.flush_input()
    steps.append("sync")
    # 2. Synchronise: M105 until one is answered (commands written during a reset are lost, so retry), then set
    #    the line counter with M110 N0. A late answer to an earlier probe is recognised as stray.
    sync_deadline = now() + timeout_s
    while True:
        remaining = sync_deadline - now()
        if remaining <= 0:
            raise HandshakeTimeoutError(_silence_explanation(link, timeout_s), step="sync")
        try:
            if link.requires_numbers:
                # This firmware runs only numbered lines; M110 is the one numbered line it accepts whatever its line
                # counter says, and it sets the counter for what follows.
                await link.send("M110 N0", timeout_s=min(1.0, remaining))
            else:
                await link.send("M105", timeout_s=min(1.0, remaining), numbered=False)
            break
        except (CommandTimeoutError, PrinterResetError, ChecksumRequiredError):
            continue
        except PrinterLockedError:
            await _unlock(link, password, timeout_s)
            continue
        except PrinterHaltedError as exc:
            raise HandshakeError(f"{exc}; reset the printer (power cycle or reset button)", step="sync") from exc
    try:
        await send_until_processed(link, "M110 N0", timeout_s=timeout_s)
    except PrinterLockedError:
        await _unlock(link, password, timeout_s)
        await send_until_processed(link, "M110 N0", timeout_s=timeout_s)
    except CommandTimeoutError as exc:
        raise HandshakeTimeoutError(f"the printer did not answer M110 N0: {exc}", step="sync") from exc
    steps.append("identify")
    # 3. Identify: M115 gives the firmware name and capabilities (collected from events as they arrive).
    try:
        await send_until_processed(link, "M115", timeout_s=timeout_s)
    except CommandTimeoutError as exc:
        raise HandshakeTimeoutError(f"the printer did not answer M115: {exc}", step="identify") from exc
    # A board's banner can come during the boot wait or, from a slow bootloader, while the first M105 waits: both
    # are the reset of this open.
    return link.stats().resets > 0


#: How many times the M110 that starts a print (or the handshake) is sent while the printer keeps talking.
M110_ATTEMPTS = 3


async def send_until_processed(link: Link, command: str, *, timeout_s: float) -> None:
    """Send a command that is harmless to run twice and whose reply lines nobody needs (M110 N0, M115), and return
    once the printer has shown that it processed it: a lost ok costs a probe, not the connection or the print.

    An answer to a later command proves it ran (Marlin answers in order; the connection then fails it with
    `LostReplyError`). Without one, it times out after a short wait and an M105 is written behind it: if that is
    answered, the command ran. Otherwise it is written again, until `timeout_s` has passed.

    Raises:
        CommandTimeoutError: the printer answered nothing for `timeout_s`.
    """
    if command.startswith("M110"):
        # The connection itself writes an unanswered M110 again, then asks with a probe numbered as if it took
        # effect (nothing else may go behind an M110), and its reply says whether it ran. On a noisy link that
        # recovery can outlast one timeout (a damaged M110, a probe delay, a damaged probe): M110 N0 is harmless to
        # run twice, so it is sent again while the printer has not been silent for `timeout_s` on end, up to
        # M110_ATTEMPTS times.
        for attempt in range(1, M110_ATTEMPTS + 1):
            try:
                await link.send(command, timeout_s=timeout_s)
            except LostReplyError:
                return
            except CommandTimeoutError:
                heard = link.trace.last_received
                if attempt == M110_ATTEMPTS or heard is None or link.now() - heard.time_s >= timeout_s:
                    raise  # silent all along: a printer that is gone, not a noisy link
                continue
            return
    deadline = link.now() + timeout_s
    while True:
        step = max(min(2.0, timeout_s / 4, deadline - link.now()), 0.05)
        try:
            await link.send(command, timeout_s=step)
            return
        except LostReplyError:
            return
        except CommandTimeoutError:
            if link.now() >= deadline:
                raise
        try:
            # Unnumbered, so a line counter the command may not have set cannot get it rejected.
            probe_timeout = max(min(2.0, timeout_s / 4, deadline - link.now()), 0.05)
            await link.send("M105", timeout_s=probe_timeout, numbered=link.requires_numbers)
            return  # answered behind it: the command was processed, only its ok was lost
        except (CommandTimeoutError, LostReplyError) as exc:
            if link.now() >= deadline:
                raise CommandTimeoutError(
                    f"no answer to {redact(command)!r} within {timeout_s:g} s: {exc}", command=redact(command)
                ) from exc


async def _unlock(link: Link, password: str | None, timeout_s: float) -> None:
    """Unlock a PASSWORD_FEATURE printer with the password given to `connect()`, or fail clearly.

    Raises:
        PrinterLockedError: no password was given, or the printer refused it.
        HandshakeTimeoutError: the printer did not answer the M511.
    """
    if password is None:
        raise PrinterLockedError(
            f"the printer on {link.port} is locked (it said 'Printer locked! (Unlock with M511 or LCD)'): "
            "connect with password=... (marlin-temp: $MARLIN_PASSWORD or --password-file) to send M511 P<password>, "
            "or unlock it on its screen"
        )
    try:
        reply = await link.send(f"M511 P{password}", timeout_s=timeout_s)
    except CommandTimeoutError as exc:
        # The message is built from redacted text (`marlin_aio.protocol.secrets`): the password never shows in it.
        raise HandshakeTimeoutError(f"the printer did not answer the password (M511 ****): {exc}", step="sync") from exc
    if any("incorrect" in line.lower() for line in reply.lines):
        raise PrinterLockedError(
            f"the printer on {link.port} refused the password ({' '.join(reply.lines)}); it stays locked"
        )


def _chatter_explanation(link: Link, bound_s: float, step: str) -> str:
    """Why a handshake outlasted its bound: the port talked all along (a silent one fails its step sooner)."""
    stats = link.stats()
    port = link.port
    head = f"no handshake with {port} within {bound_s:g} s ({HANDSHAKE_TIMEOUTS} timeouts; stuck at {step})"
    if stats.garbage_lines:
        others = " or ".join(str(rate) for rate in BAUD_RATES if rate != link.baudrate)
        return (
            f"{head}: it kept sending ({stats.bytes_received} bytes, {stats.garbage_lines} lines of garbage) but "
            f"never answered like a printer; wrong baud rate? {link.baudrate} is set (Marlin boards use {others}), "
            "or not a printer's port"
        )
    said = [entry.text for entry in link.trace.entries() if entry.direction == "received"][-3:]
    quoted = "; it said: " + " | ".join(repr(line) for line in said) if said else ""
    return f"{head}: it kept sending ({stats.bytes_received} bytes) but never answered like a printer{quoted}"


def _silence_explanation(link: Link, timeout_s: float) -> str:
    stats = link.stats()
    port = link.port
    if stats.bytes_received == 0:
        return (
            f"no answer from {port} within {timeout_s:g} s: nothing was received "
            "(is this the printer's port, and is it powered?)"
        )
    if stats.garbage_lines:
        others = " or ".join(str(rate) for rate in BAUD_RATES if rate != link.baudrate)
        return (
            f"no answer from {port} within {timeout_s:g} s: {stats.bytes_received} bytes of garbage "
            f"received; wrong baud rate? {link.baudrate} is set (Marlin boards use {others})"
        )
    said = [entry.text for entry in link.trace.entries() if entry.direction == "received"][-3:]
    quoted = "; it said: " + " | ".join(repr(line) for line in said) if said else ""
    return f"no 'ok' from {port} within {timeout_s:g} s, though it sent {stats.bytes_received} bytes{quoted}"
