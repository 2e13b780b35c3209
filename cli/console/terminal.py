"""`marlin-temp terminal`: an interactive G-code console with history, completion and the emergency stop on a key.

prompt_toolkit edits the line (`PromptSession.prompt_async`, on the command's own event loop) and prints replies
above it. The prompt is back as soon as a line is entered: each command runs in a task of its own, so the prompt,
and with it F12 (the emergency stop), stays live while a G28 or an M109 takes its time. Commands still go to the
printer one after another, in the order typed, and each reply is printed when it comes.

Temperatures are polled in the background (M105, plus M155 auto-reports where the firmware has them, so they keep
coming while a long command blocks the queue); the polls' answers are never printed. The latest reading is in
the bottom bar, and a compact line goes into the scrollback now and then (`temperature_every_s`), only when
something changed, so an idle printer does not flood the screen.

Nothing reaches the printer that the user did not mean. F12 sends the emergency stop at once; M112 typed (in any
spelling Marlin reads as M112, see `is_emergency_stop`) or `!` and Enter asks first, one key: `y` sends, any other
key does not. M112 is never completed and never kept in the history (`HistoryWithoutStops`), so Tab or Up, Enter
cannot send it by accident. A command the library refuses (`M104 S999` above --max-hotend) is one error line;
whatever a background task raises becomes one line too, never an exception in prompt_toolkit's event loop (which
would stop the prompt and swallow the next line typed). Firmware text is printed as prompt_toolkit plain text:
no markup or emoji codes are read in it.

Over 400 lines because the console is one prompt_toolkit session: the history, the completion, the key bindings
(F12), the background polls and the printing of replies share its event loop and must agree on who prints when.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from prompt_toolkit import PromptSession
from prompt_toolkit.application import Application, get_app_or_none, get_app_session, run_in_terminal
from prompt_toolkit.completion import CompleteEvent, Completer, Completion
from prompt_toolkit.document import Document
from prompt_toolkit.formatted_text import FormattedText
from prompt_toolkit.history import FileHistory, History, InMemoryHistory
from prompt_toolkit.input.typeahead import clear_typeahead
from prompt_toolkit.key_binding import KeyBindings, KeyPressEvent
from prompt_toolkit.keys import Keys
from prompt_toolkit.layout import FormattedTextControl, Layout, Window
from prompt_toolkit.patch_stdout import patch_stdout
from prompt_toolkit.renderer import print_formatted_text
from prompt_toolkit.styles import Style
from rich.console import Console

import marlin_aio
from marlin_aio import TemperatureReading
from marlin_aio.protocol import command_code, command_timeout_s, heater_name

from ..common.connect import ConnectOptions, Exit, open_printer
from ..common.prompts import buttons_text, prompt_text, request_text
from .send import check_command, emergency_stop_notes, reply_lines, unknown_command

__all__ = [
    "EMERGENCY_STOP_KEY",
    "GCODES",
    "ConsoleSettings",
    "GcodeCompleter",
    "HistoryWithoutStops",
    "default_history_path",
    "is_emergency_stop",
    "run_console",
    "temperature_line",
]

#: The key that sends the emergency stop at once (typing `!` or `M112` and Enter asks first).
EMERGENCY_STOP_KEY = "f12"

#: The codes the completer offers, with what each does (Marlin 2.1). M112 is not among them: a Tab must never
#: complete a line into the emergency stop.
GCODES: dict[str, str] = {
    "G0": "travel move",
    "G1": "linear move (X Y Z E F)",
    "G4": "dwell (P ms or S s)",
    "G28": "home (all, or X Y Z)",
    "G29": "bed levelling probe",
    "G90": "absolute positions",
    "G91": "relative positions",
    "G92": "set the current position",
    "M17": "motors on",
    "M18": "motors off",
    "M20": "list the SD card",
    "M24": "start or resume the SD print",
    "M25": "pause the SD print",
    "M27": "SD print status",
    "M82": "absolute extrusion",
    "M83": "relative extrusion",
    "M84": "motors off (X Y Z E)",
    "M104": "hotend target (S C), no wait",
    "M105": "report temperatures",
    "M106": "fan speed (S0-255)",
    "M107": "fan off",
    "M108": "stop waiting for heaters",
    "M109": "hotend target and wait",
    "M114": "report position",
    "M115": "firmware and capabilities",
    "M117": "message on the display",
    "M119": "endstop states",
    "M140": "bed target (S C), no wait",
    "M141": "chamber target (S C)",
    "M155": "temperature auto-report (S seconds)",
    "M190": "bed target and wait",
    "M220": "speed factor (S percent)",
    "M221": "flow factor (S percent)",
    "M301": "hotend PID values",
    "M303": "PID autotune",
    "M400": "wait for moves to finish",
    "M410": "quick stop (planned moves dropped)",
    "M500": "save settings to EEPROM",
    "M501": "load settings from EEPROM",
    "M502": "factory settings",
    "M503": "report settings",
    "M999": "resume after an error stop",
}

#: The console's own words: never sent to the printer.
_LOCAL = {
    "help": "what the console understands",
    "temps": "the temperatures now",
    "answer": "answer N: pick button N of the printer's prompt (M876)",
    "quit": "leave (as Ctrl-D does)",
    "exit": "leave (as Ctrl-D does)",
}

_HELP = (
    "Type G-code and press Enter: the reply is printed when it comes, and you can type on meanwhile.",
    "Tab completes codes. Up and Down walk the history (kept across sessions); Ctrl-R searches it.",
    "Ctrl-C clears the line; Ctrl-D (or quit) leaves.",
    "F12 sends the emergency stop at once, ahead of anything queued; M112 (or !) and Enter asks first.",
    "M112 is never completed or kept in the history.",
    "temps: the temperatures now (the bar at the bottom follows them; a line is added when they change).",
    "answer N: pick button N (from 1) of the prompt the printer shows (a filament change); M876 goes at once.",
)

_STYLE = Style.from_dict(
    {
        "command": "bold",
        "temperatures": "ansicyan",
        "note": "ansiyellow",
        "error": "ansired bold",
        "stop": "ansiwhite bg:ansired bold",
    }
)


@dataclass(frozen=True)
class ConsoleSettings:
    """How the console polls and shows temperatures, and where it keeps its history (None: this session only)."""

    poll_interval_s: float = 1.0
    temperature_every_s: float = 30.0
    history_path: Path | None = None


# `command_code` reads a line as Marlin's parser.cpp does (`m112`, `M0112`, `M 112`, `N5 M112*12`, `M112.0`).
# Marlin's other reader, the emergency parser (emergency_parser.h), acts on M112 as it arrives and is looser
# about the line number: `N` with blanks or nothing before the M (`N 5 M112`, `NM112`). This pattern takes what
# either reader would, and still catches parser.cpp's spellings should `command_code` ever change.
_M112 = re.compile(r"\s*(?:N[\d\s-]*)?M\s*0*112(?!\d)", re.IGNORECASE)

_STOP_QUESTION = "send the emergency stop M112? the printer halts and needs a reset. y = send, any other key = don't "


def is_emergency_stop(text: str) -> bool:
    """Would this line, sent, be the emergency stop: M112 in any spelling Marlin reads as M112 (`m112`, `M0112`,
    `M 112`, `N5 M112*12`, with a comment), or the console's own `!`?"""
    line = text.strip()
    return line == "!" or command_code(line) == "M112" or _M112.match(line) is not None


def _kept_out_of_history(line: str) -> bool:
    """The emergency stop (never to be repeated by Up, Enter) and a password (M511, never to be left in a file)."""
    return is_emergency_stop(line) or marlin_aio.redact(line) != line


class HistoryWithoutStops(History):
    """A history (a file's, or this session's) that never holds the emergency stop: M112 is not written to it, not
    recalled from it in this session, and not loaded from an old file that has it (older versions kept it). A
    printer password typed as `M511 P...` is kept out the same way.

    Composed over the history it filters, so the file format and its locking stay prompt_toolkit's.
    """

    def __init__(self, inner: History) -> None:
        super().__init__()
        self.inner = inner

    def load_history_strings(self) -> Iterable[str]:
        """The inner history's lines, newest first, without the emergency stop."""
        return (line for line in self.inner.load_history_strings() if not _kept_out_of_history(line))

    def append_string(self, string: str) -> None:
        """Keep an entered line for Up and Ctrl-R (and the file), unless it is the emergency stop."""
        if not _kept_out_of_history(string):
            super().append_string(string)

    def store_string(self, string: str) -> None:
        """Write a line to the inner history (never the emergency stop)."""
        if not _kept_out_of_history(string):
            self.inner.store_string(string)


def default_history_path(environ: Mapping[str, str] = os.environ) -> Path:
    """`$XDG_STATE_HOME/marlin-temp/history`, or `~/.local/state/marlin-temp/history` (the XDG default).

    A relative XDG_STATE_HOME is ignored, as the XDG specification says.
    """
    state = environ.get("XDG_STATE_HOME", "")
    base = Path(state) if state and Path(state).is_absolute() else Path.home() / ".local" / "state"
    return base / "marlin-temp" / "history"


class GcodeCompleter(Completer):
    """Completes the first word of a line: the common G and M codes with what they do, and the console's words."""

    def get_completions(self, document: Document, complete_event: CompleteEvent) -> Iterable[Completion]:
        """The codes that start with what was typed (in any case), each with a short description."""
        typed = document.text_before_cursor.lstrip()
        if " " in typed:
            return  # past the code: parameters are the user's
        word = typed.upper()
        for code, meaning in GCODES.items():
            if code.startswith(word) and not is_emergency_stop(code):
                yield Completion(code, start_position=-len(typed), display_meta=meaning)
        for name, meaning in _LOCAL.items():
            if typed and name.startswith(typed.lower()):
                yield Completion(name, start_position=-len(typed), display_meta=meaning)


def temperature_line(reading: TemperatureReading) -> str:
    """`hotend 198.2/200 C  bed 25.1 C off`: every heater of a reading, hotends first (the active one once)."""
    heaters = reading.temperatures.heaters
    keys = sorted(heaters, key=lambda key: key[:1] != "T")  # stable: otherwise in the report's order
    parts = []
    for key in keys:
        if key == "T" and "T0" in heaters:
            continue  # the active hotend is listed again under its number
        heater = heaters[key]
        if heater.target:
            parts.append(f"{heater_name(key)} {heater.actual:.1f}/{heater.target:.0f} C")
        else:
            parts.append(f"{heater_name(key)} {heater.actual:.1f} C{'' if heater.target is None else ' off'}")
    return "  ".join(parts) or "no temperatures reported"


def _changed(reading: TemperatureReading, shown: TemperatureReading | None) -> bool:
    """Worth a new line: a heater came or went, a target changed, or a temperature moved by a degree or more."""
    if shown is None:
        return True
    now, before = reading.temperatures.heaters, shown.temperatures.heaters
    if now.keys() != before.keys():
        return True
    return any(h.target != before[k].target or abs(h.actual - before[k].actual) >= 1.0 for k, h in now.items())


class _Console:
    """One interactive session on an open printer."""

    def __init__(self, printer: marlin_aio.Printer, label: str, settings: ConsoleSettings) -> None:
        self.printer = printer
        self.label = label
        self.settings = settings
        self.session: PromptSession[str] | None = None
        self.running: set[asyncio.Task[None]] = set()
        self.printing: set[asyncio.Future[None]] = set()
        # Bumped by every line that reaches the screen (an entered line, a reply, a temperature line): a reply that
        # does not come right under its command gets the command as a title.
        self.screen_serial = 0
        self.shown: TemperatureReading | None = None
        self.shown_at = float("-inf")
        self.halted = False
        self.failure: marlin_aio.MarlinError | None = None  # the link went away: the session ends with it
        self.quit = False
        self.question: Application[bool] | None = None  # the emergency stop's question, while it is asked

    @property
    def limits(self) -> marlin_aio.HeaterLimits:
        """The printer's target limits (--max-hotend, --max-bed): a line is checked against them as it is entered,
        so a refusal is said right under it; the client checks again as it sends."""
        return self.printer.heater_limits

    # --------------------------------------------------------------------------------------- output

    def say(self, text: str, style: str = "") -> None:
        self.show(lambda: [(style, text)])

    def show(self, lines: Callable[[], list[tuple[str, str]]]) -> None:
        """Print lines above the prompt. `lines` is called when they are written, not when they were asked for
        (the prompt may be redrawn in between), so it can see what is on the screen by then."""
        output = get_app_session().output

        def render() -> None:
            try:
                shown = lines()
            except Exception as exc:  # a bug in making the lines: say so in their place, never lose them silently
                shown = [("class:error", f"error: {_one_line(exc)}")]
            fragments: list[tuple[str, str]] = []
            for style, text in shown:
                fragments += [(style, text), ("", "\n")]
            print_formatted_text(output, FormattedText(fragments), _STYLE)
            output.flush()
            self.screen_serial += 1

        app = get_app_or_none()
        if app is None or not app.is_running:
            render()
            return
        printed = asyncio.ensure_future(run_in_terminal(render))
        self.printing.add(printed)  # the loop keeps only a weak reference to the task
        printed.add_done_callback(self.printing.discard)
        printed.add_done_callback(_printed)

    def show_temperatures(self, reading: TemperatureReading | None) -> None:
        if reading is None:
            self.say("no temperatures yet", "class:note")
            return
        self.shown, self.shown_at = reading, reading.monotonic_s
        self.say(temperature_line(reading), "class:temperatures")

    def toolbar(self) -> FormattedText:
        """The bottom bar: the latest temperatures, what is running, the keys."""
        if self.halted:
            state = [("class:stop", " HALTED: reset the printer to go on ")]
        else:
            latest = self.printer.latest
            state = [("", f" {temperature_line(latest) if latest else 'waiting for temperatures'}")]
        busy = f"  | running: {len(self.running)}" if self.running else ""
        keys = "F12 emergency stop (M112 or ! asks first)  | Ctrl-D quits"
        return FormattedText([*state, ("", f"{busy}  | {keys}  | {self.label}")])

    # --------------------------------------------------------------------------------------- input

    def key_bindings(self) -> KeyBindings:
        bindings = KeyBindings()

        @bindings.add(EMERGENCY_STOP_KEY, eager=True)
        def _(event: KeyPressEvent) -> None:
            self.emergency_stop()

        return bindings

    def emergency_stop(self) -> None:
        """Write M112 now. Also run from a key binding: nothing may raise out of it into prompt_toolkit's loop."""
        try:
            self.printer.emergency_stop()
        except Exception as exc:  # a lost link, or a bug: one line either way, the prompt lives on
            self.say(f"error: the emergency stop was not sent: {_one_line(exc)}", "class:error")
            return
        self.halted = True
        self.show(lambda: [("class:stop", note) for note in emergency_stop_notes(self.printer.capabilities)])

    async def ask_to_stop(self) -> None:
        """M112 (or !) was typed: send it only if the next key is `y` (F12, the stop's own key, sends it too)."""
        try:
            send = await self.ask(_STOP_QUESTION)
        except EOFError:  # the link went away while asking: there is nothing to send the stop to
            send = False
        if send:
            self.emergency_stop()
        else:
            self.say("emergency stop not sent: nothing was written to the printer", "class:note")

    async def ask(self, question: str) -> bool:
        """Show `question` and wait for one key: True for `y`, False for any other (Enter, Esc, Ctrl-C, a paste).

        Keys typed before the question was shown are dropped: an answer is a key pressed after it.
        """
        bindings = KeyBindings()

        @bindings.add(Keys.Any)
        def _(event: KeyPressEvent) -> None:
            key = event.key_sequence[0].key
            if key in _NOT_KEYS:
                return  # the terminal reporting something, not a person pressing a key
            event.app.exit(result=key in ("y", "Y"))

        @bindings.add(EMERGENCY_STOP_KEY, eager=True)
        def _(event: KeyPressEvent) -> None:
            event.app.exit(result=True)

        clear_typeahead(get_app_session().input)
        self.question = Application(
            layout=Layout(Window(FormattedTextControl([("class:stop", question)]), dont_extend_height=True)),
            key_bindings=bindings,
            style=_STYLE,
            erase_when_done=False,
        )
        try:
            return await self.question.run_async(pre_run=self.leave_if_ended)
        finally:
            self.question = None
            self.screen_serial += 1  # the question and its answer stay on the screen

    async def handle(self, text: str) -> None:
        """Act on one entered line: a word of the console's, the emergency stop, or a command for the printer."""
        self.screen_serial += 1  # the entered line stays on the screen above the next prompt
        line = text.strip()
        word = line.lower()
        if not line:
            return
        if is_emergency_stop(line):
            await self.ask_to_stop()
        elif word in ("quit", "exit"):
            self.quit = True
        elif word == "help":
            for help_line in _HELP:
                self.say(help_line, "class:note")
        elif word == "temps":
            self.show_temperatures(self.printer.latest)
        elif word.split()[0] == "answer":
            await self.answer(word.split()[1:])
        else:
            try:
                command = check_command(line, limits=self.limits)
            except ValueError as exc:
                self.say(f"error: {_one_line(exc)} (not sent)", "class:error")
                return
            task = asyncio.create_task(
                self.guarded(self.run_command(command, self.screen_serial), command), name=f"console {command}"
            )
            self.running.add(task)
            task.add_done_callback(self.running.discard)

    async def answer(self, words: list[str]) -> None:
        """`answer N`: pick button N (from 1) of the printer's open prompt; a wrong N is one line, nothing sent."""
        prompt = self.printer.prompt
        if prompt is None:
            self.say("error: the printer shows no prompt to answer (not sent)", "class:error")
            return
        if len(words) != 1 or not words[0].isdigit() or not 1 <= int(words[0]) <= len(prompt.buttons):
            self.say(f"error: answer takes one of {buttons_text(prompt)} (not sent)", "class:error")
            return
        index = int(words[0]) - 1
        try:
            await self.printer.answer_prompt(index)
        except (ValueError, marlin_aio.MarlinError) as exc:
            self.say(f"error: {_one_line(exc)}", "class:error")
            return
        self.say(f"answered the printer: {prompt.buttons[index]} (M876 S{index})", "class:note")

    def on_request(self, request: marlin_aio.HostRequest) -> None:
        """Put what the printer asks into the scrollback as it asks it (`Printer.on_host_request`)."""
        if request.action in ("prompt", "paused_for_user"):
            text = prompt_text(self.printer.prompt, self.printer.waiting_for_user, press="type answer")
        else:
            text = request_text(request.action, request.argument)
        if text is not None:
            self.say(text, "class:note")

    async def guarded(self, work: Awaitable[None], what: str) -> None:
        """Run a background task's work: whatever it raises becomes one error line, never an exception in
        prompt_toolkit's event loop ("Unhandled exception in event loop ... Press ENTER", which also takes the
        next line typed)."""
        try:
            await work
        except Exception as exc:  # a bug of ours or the library's: one line, the prompt lives on
            self.say(f"error: {what}: {_one_line(exc)}", "class:error")

    async def run_command(self, command: str, entered_at: int) -> None:
        timeout_s = command_timeout_s(command, self.printer.timeout_s)
        try:
            reply = await self.printer.send(command, timeout_s=timeout_s)
        except ValueError as exc:  # refused before anything was written: a target above the limits, ...
            self.say(f"error: {marlin_aio.redact(command)}: {_one_line(exc)} (not sent)", "class:error")
            return
        except marlin_aio.MarlinError as exc:
            self.say(f"error: {marlin_aio.redact(command)}: {_one_line(exc)}", "class:error")
            if isinstance(exc, marlin_aio.PrinterHaltedError):
                self.halted = True
            elif isinstance(exc, marlin_aio.ConnectionLostError):
                self.end(exc)
            return

        def reply_text() -> list[tuple[str, str]]:
            title = [] if self.screen_serial == entered_at else [("class:command", f"[{command}]")]
            text = [("", line) for line in reply_lines(reply)]
            if unknown_command(reply):
                text.append(("class:note", f"the printer does not know {command_code(command)}: nothing ran"))
            return title + text

        self.show(reply_text)

    # --------------------------------------------------------------------------------------- background

    async def follow_temperatures(self) -> None:
        """Keep a compact line in the scrollback now and then; notice a halt or a lost link."""
        every_s = self.settings.temperature_every_s
        try:
            async for reading in self.printer.temperature_readings():
                if every_s > 0 and reading.monotonic_s - self.shown_at >= every_s and _changed(reading, self.shown):
                    self.show_temperatures(reading)
        except marlin_aio.PrinterHaltedError as exc:
            if not self.halted:  # not our own emergency stop: thermal protection, a kill on the board, ...
                self.say(f"error: {_one_line(exc)}", "class:error")
            self.halted = True
        except marlin_aio.MarlinError as exc:
            self.end(exc)  # the link is gone (or the board reset): said once, as the session's error

    def end(self, failure: marlin_aio.MarlinError) -> None:
        """The link is gone: leave the prompt, and the session ends with this error."""
        self.failure = failure
        self.leave_if_ended()

    def leave_if_ended(self) -> None:
        # Also run as each prompt (and the stop's question) starts, for a failure that came while none was up.
        if self.failure is None:
            return
        for app in (self.session.app if self.session is not None else None, self.question):
            if app is not None and app.is_running and not app.is_done:
                app.exit(exception=EOFError())

    # --------------------------------------------------------------------------------------- the session

    async def run(self, history: History) -> Exit:
        firmware = self.printer.firmware.name if self.printer.firmware else "unknown firmware"
        self.say(f"connected to {self.label}: {firmware}", "class:note")
        self.say(
            "F12: emergency stop at once (M112 or ! and Enter asks first).  Ctrl-D: quit.  help: what else there is.",
            "class:note",
        )
        self.session = PromptSession(
            history=history,
            completer=GcodeCompleter(),
            complete_while_typing=True,
            key_bindings=self.key_bindings(),
            bottom_toolbar=self.toolbar,
            refresh_interval=0.5,
            style=_STYLE,
        )
        polling = contextlib.AsyncExitStack()
        polling.callback(self.printer.on_host_request(self.on_request))
        await polling.enter_async_context(self.printer.poll_temperatures(self.settings.poll_interval_s))
        follower = asyncio.create_task(
            self.guarded(self.follow_temperatures(), "following the temperatures"), name="console temperatures"
        )
        try:
            await self.prompt_loop(self.session)
        finally:
            abandoned = bool(self.running)
            follower.cancel()
            for task in list(self.running):
                task.cancel()  # one still waiting to be written never is; one written runs on the printer
            await asyncio.gather(follower, *self.running, return_exceptions=True)
            await asyncio.gather(*self.printing, return_exceptions=True)  # what is still to print, printed
            # Stopping the polls turns M155 off, which queues behind a command still running on the printer (a
            # long dwell, a heat-up): not worth a wait for that. Unsent, it is never written.
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(1.0 if abandoned else None):
                    await polling.aclose()
        if self.failure is not None:
            raise self.failure
        return Exit.HALTED if self.halted else Exit.OK

    async def prompt_loop(self, session: PromptSession[str]) -> None:
        while not self.quit and self.failure is None:
            try:
                text = await session.prompt_async("marlin> ", pre_run=self.leave_if_ended)
            except KeyboardInterrupt:
                continue  # Ctrl-C: the line is dropped, the session goes on
            except EOFError:
                break
            await self.guarded(self.handle(text), text.strip())
        if self.running:
            waiting = ", ".join(task.get_name().removeprefix("console ") for task in self.running)
            self.say(f"left without waiting for: {waiting}", "class:note")


# Key "presses" that are the terminal answering a query or a mouse report: no answer to a question.
_NOT_KEYS = frozenset({Keys.CPRResponse, Keys.Vt100MouseEvent, Keys.Ignore, Keys.ScrollUp, Keys.ScrollDown})


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (its type's name if it has none)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def _printed(printed: asyncio.Future[None]) -> None:
    # A line that could not be printed (the terminal gone) has nowhere to say so; its exception is taken here so
    # the loop does not report it ("exception was never retrieved") over the prompt.
    if not printed.cancelled():
        printed.exception()


def _open_history(path: Path | None) -> tuple[History, str | None]:
    """The history file (created if need be), or one for this session only with the reason why; either without
    the emergency stop."""
    if path is None:
        return HistoryWithoutStops(InMemoryHistory()), None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch(exist_ok=True)
    except OSError as exc:
        return HistoryWithoutStops(InMemoryHistory()), f"history not kept ({exc.strerror or exc}: {path})"
    return HistoryWithoutStops(FileHistory(str(path))), None


async def run_console(options: ConnectOptions, settings: ConsoleSettings, errors: Console) -> Exit:
    """Open the printer and run the interactive console until Ctrl-D; return the exit code (7 after the emergency
    stop: the printer is halted).

    Raises:
        MarlinError: opening failed, or the link went away during the session.
    """
    history, problem = _open_history(settings.history_path)
    if problem is not None:
        errors.print(problem, style="dim", markup=False, emoji=False, highlight=False)
    async with open_printer(options, errors) as (printer, label):
        with patch_stdout(raw=True):
            return await _Console(printer, label, settings).run(history)
    raise AssertionError("unreachable")  # pragma: no cover  (mypy cannot see that `async with` returns)
