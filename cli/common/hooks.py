"""`--on-done CMD`: a shell command run once when `set --wait` or `print` ends, with the outcome in its environment,
so a phone notification is one line of shell (`--on-done 'curl -d "$MARLIN_TEMP_MESSAGE" ntfy.sh/mytopic'`).

The command runs through `sh -c` with the environment of marlin-temp plus:

- `MARLIN_TEMP_EVENT`: `set` or `print`;
- `MARLIN_TEMP_OUTCOME`: `reached`, `cool`, `timeout` (set); `done`, `cancelled`, `halted` (print); `failed`,
  `lost`, `interrupted` (either);
- `MARLIN_TEMP_EXIT`: the exit code marlin-temp exits with;
- `MARLIN_TEMP_MESSAGE`: one line saying it;
- `MARLIN_TEMP_PORT`: the printer's port; `MARLIN_TEMP_FILE`: the G-code file (print);
- `MARLIN_TEMP_ELAPSED_S`: seconds from the start of the command to the end, whole.

marlin-temp waits for it, at most `HOOK_TIMEOUT_S` (then it is killed, its children too, with a warning). Its
output goes to marlin-temp's stderr, so the stdout of `--json` and friends stays the command's own. A command that
fails is one warning line and never changes marlin-temp's exit code: the notification is not the job.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

from rich.console import Console

import marlin_aio

from .connect import Exit, UsageProblem, exit_code_for

__all__ = ["HOOK_TIMEOUT_S", "Done", "outcome_of_error", "run_on_done", "with_on_done"]

#: How long marlin-temp waits for an --on-done command before killing it.
HOOK_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class Done:
    """How a command ended, as the --on-done command is told it."""

    event: str
    outcome: str
    exit_code: int
    message: str
    port: str = ""
    file: str = ""
    elapsed_s: float = 0.0

    def environment(self) -> dict[str, str]:
        """The variables the command gets (besides marlin-temp's own environment)."""
        env = {
            "MARLIN_TEMP_EVENT": self.event,
            "MARLIN_TEMP_OUTCOME": self.outcome,
            "MARLIN_TEMP_EXIT": str(self.exit_code),
            # One line: a message read by a notification service must not be cut at a line break it did not expect.
            "MARLIN_TEMP_MESSAGE": " ".join(self.message.split()),
            "MARLIN_TEMP_PORT": self.port,
            "MARLIN_TEMP_ELAPSED_S": str(round(self.elapsed_s)),
        }
        if self.file:
            env["MARLIN_TEMP_FILE"] = self.file
        return env


async def run_on_done(command: str, done: Done, errors: Console, *, timeout_s: float = HOOK_TIMEOUT_S) -> None:
    """Run `command` through `sh -c` with `done` in its environment and wait for it (at most `timeout_s`, then it
    and its children are killed); a failure is one warning line on `errors`, never raised."""
    # Its own session: a timeout kills the whole group (`sh -c 'curl ...'` leaves curl otherwise), and a Ctrl-C
    # meant for marlin-temp's print does not reach it.
    try:
        process = await asyncio.create_subprocess_exec(
            "sh",
            "-c",
            command,
            env=os.environ | done.environment(),
            stdin=asyncio.subprocess.DEVNULL,
            stdout=_stderr_fd(),
            start_new_session=True,
        )
    except OSError as exc:
        _warn(errors, f"--on-done could not run: {exc.strerror or exc}")
        return
    try:
        async with asyncio.timeout(timeout_s):
            code = await process.wait()
    except TimeoutError:
        _kill(process)
        await process.wait()  # reaped: SIGKILL cannot be ignored, so this is at once
        _warn(errors, f"--on-done was still running after {timeout_s:g} s: stopped")
        return
    except BaseException:  # Ctrl-C or a cancel while it runs: it must not outlive marlin-temp
        _kill(process)
        raise
    if code != 0:
        _warn(errors, f"--on-done exited with code {code}" + (" (command not found)" if code == 127 else ""))


def _stderr_fd() -> int:
    # Under a test runner sys.stderr may be a buffer without a descriptor: the process's own stderr then.
    try:
        return sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        return 2


def _kill(process: asyncio.subprocess.Process) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, signal.SIGKILL)


def _warn(errors: Console, text: str) -> None:
    errors.print(f"warning: {text}", style="yellow", markup=False, emoji=False, soft_wrap=True)


def outcome_of_error(exc: BaseException) -> tuple[str, int]:
    """The outcome name and exit code of a command that ended with `exc`."""
    if isinstance(exc, KeyboardInterrupt | asyncio.CancelledError):
        return "interrupted", Exit.INTERRUPTED
    if isinstance(exc, marlin_aio.MarlinError):
        code = exit_code_for(exc)
        if isinstance(exc, marlin_aio.TemperatureTimeoutError):
            return "timeout", code
        if isinstance(exc, marlin_aio.PrinterHaltedError):
            return "halted", code
        if isinstance(exc, marlin_aio.ConnectionLostError):
            return "lost", code
        return "failed", code
    if isinstance(exc, UsageProblem):
        return "failed", exc.code
    return "failed", Exit.ERROR


async def with_on_done(
    body: Awaitable[Exit],
    command: str | None,
    errors: Console,
    describe: Callable[[Exit | None, BaseException | None, float], Done],
) -> Exit:
    """Await `body` (a command's async body) and then, with `command`, run it as `run_on_done` says, with what
    `describe(code, error, elapsed_s)` makes of the end (`code` when it returned, `error` when it raised);
    return the body's code or raise its error, whatever the command did.

    A bad argument found by the body (`UsageProblem`, exit 2) runs nothing: nothing happened to tell of.
    """
    if command is None:
        return await body
    started = time.monotonic()
    try:
        code = await body
    except UsageProblem:
        raise
    except BaseException as exc:
        await run_on_done(command, describe(None, exc, time.monotonic() - started), errors)
        raise
    await run_on_done(command, describe(code, None, time.monotonic() - started), errors)
    return code
