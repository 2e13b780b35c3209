"""`marlin-temp job` at work: the served printer's job read, followed or steered through the service's verbs."""

from __future__ import annotations

import asyncio
import json
from typing import Any

from rich.console import Console

import marlin_aio

from ..common.connect import ConnectOptions, Exit, UsageProblem, open_printer

__all__ = ["describe_job", "run_job"]

#: How often `attach` reads the job while it runs.
ATTACH_EVERY_S = 0.5
_ENDED = {"done": Exit.OK, "cancelled": Exit.INTERRUPTED, "failed": Exit.ERROR, "interrupted": Exit.LOST}


def describe_job(job: dict[str, Any]) -> str:
    """One line for people: the file, the printer, the state and percent, who started it, where to resume."""
    percent = "" if job.get("percent") is None else f", {job['percent']:g} %"
    text = f"{job['file']} on {job['printer']}: {job['state']}{percent}, started by {job['started_by']}"
    if job.get("cancelled_by"):
        text += f", cancelled by {job['cancelled_by']}"
    if job.get("error"):
        text += f"; {job['error']}"
    if job["state"] in ("cancelled", "failed", "interrupted") and job.get("surely_run_line"):
        text += (
            f"; the printer ran line {job['surely_run_line']}"
            + (
                f" and may have run up to line {job['may_have_run_line']}"
                if job["may_have_run_line"] > job["surely_run_line"]
                else ""
            )
            + f": resume with --from-line {job['resume_line']}"
        )
    return text


async def run_job(options: ConnectOptions, action: str, json_output: bool, console: Console, errors: Console) -> Exit:
    """Do `action` to the served printer's job; return the exit code.

    Raises:
        UsageProblem: the port is not a served printer, or no job is running to pause, resume or cancel.
        MarlinError: the service or its printer failed.
    """
    if not (options.port or "").startswith("serve:"):
        raise UsageProblem("a print job is the service's: give --port serve:NAME (marlin-temp serve owns the printer)")
    async with open_printer(options, errors) as (printer, label):
        call = getattr(printer, "call", None)
        if call is None:
            raise UsageProblem(f"{label} is not a printer of marlin-temp serve")
        job = await call("job")
        if action == "status":
            if job is None:
                errors.print(f"no print job on {label} yet", markup=False)
                return Exit.NO_PORT
            console.print(json.dumps(job) if json_output else describe_job(job), markup=False)  # names are users'
            return Exit.OK
        if job is None or not job.get("active"):
            last = "" if job is None else f" (the last: {describe_job(job)})"
            raise UsageProblem(f"no print is running on {label}{last}")
        if action == "attach":
            return await _attach(call, job, console, errors, json_output)
        try:
            value = await call(action)
        except RuntimeError as exc:
            raise UsageProblem(str(exc)) from None
        ended = value.get("job", value) if action == "cancel" else value
        console.print(json.dumps(ended) if json_output else describe_job(ended), markup=False)
        return Exit.OK


async def _attach(call: Any, job: dict[str, Any], console: Console, errors: Console, json_output: bool) -> Exit:
    """Follow the job until it ends: a line whenever its state or percent changes; Ctrl-C leaves it running."""
    errors.print(f"attached to {job['file']} on {job['printer']}; Ctrl-C leaves it running", style="dim", markup=False)
    said = None
    try:
        while True:
            line = json.dumps(job) if json_output else describe_job(job)
            if line != said:
                console.print(line, markup=False)
                said = line
            if job["state"] in _ENDED:
                return _ENDED[job["state"]]
            await asyncio.sleep(ATTACH_EVERY_S)  # a ticker: the job is read at this rate, nothing waits on it
            job = await call("job")
    except asyncio.CancelledError:
        errors.print(f"left {job['file']} running in the service", style="dim", markup=False)
        raise
    except marlin_aio.ConnectionLostError as exc:
        errors.print(f"the service went away: {exc}; {describe_job(job)}", markup=False)
        return Exit.LOST
