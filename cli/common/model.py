"""What `watch` knows: the readings per heater (the last minute as read, hours of them downsampled), the figures
derived from them, and the keys.

Pure data, no I/O and no rich: the live view, the plain-line output and the tests all read the same numbers.
Readings arrive about every 10 ms, so adding one must be cheap: it appends to a deque, trims the front and updates
a bucket (`history.HeaterHistory`, whose docstring states the memory bound).

`WatchControls` turns key presses into actions (set targets, fan, a G-code line, pause, resume or cancel a served
printer's print job, quit) without touching the printer: every target is checked here, with the limits `set` uses,
so a refused one becomes a notice in the view and never an action. `watch/command.py` performs the actions and
hands their outcome back as a `Notice`.

Over 400 lines because the view's data and the keys' meaning are read together: `WatchControls` checks a target
against what `WatchModel` shows (the heaters the printer has), and offers the job's keys only while `JobStatus`
says a job runs; all of it is pure, so the tests need no printer.
"""

from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from marlin_aio import HeaterLimits, TemperatureReading
from marlin_aio.farm.presets import DEFAULT_PRESETS, Preset
from marlin_aio.protocol import DEFAULT_LIMITS, HEATER_NAMES, Prompt, check_target, command_code, heater_name

from .history import HeaterHistory, Point
from .keys import PASTE
from .prompts import answer_index

__all__ = [
    "HEATER_NAMES",
    "LATENCY_WINDOW_S",
    "PRESET_KEYS",
    "STEP_CELSIUS",
    "WINDOWS_S",
    "Action",
    "AnswerPrompt",
    "CancelJob",
    "HeaterStatus",
    "JobStatus",
    "LinkHealth",
    "Notice",
    "PauseJob",
    "Preset",
    "Quit",
    "ResumeJob",
    "SendCommand",
    "SetFan",
    "SetTargets",
    "TurnOff",
    "WatchControls",
    "WatchModel",
    "heater_name",
    "target_text",
]


def target_text(target: float | None) -> str:
    """A target as the views show it: `200`, `off` for 0, and `?` when the printer does not say (Repetier-style
    reports carry none, and no `TargetExtr0:` line has told this client one): an unknown target is not off."""
    if target is None:
        return "?"
    return "off" if target == 0 else f"{target:.0f}"


@dataclass(frozen=True, slots=True)
class HeaterStatus:
    """One heater's row: actual, target, power, rate and state, with an estimated time to target."""

    key: str
    name: str
    actual: float
    target: float | None
    power_percent: float | None
    rate_c_per_s: float | None
    state: str  # "heating", "cooling", "holding", "off"; with no target known "heating?" (powered) or "unknown"
    eta_s: float | None


@dataclass(frozen=True, slots=True)
class JobStatus:
    """A served printer's print job as the view shows it: the service's `job` answer, read into fields."""

    file: str
    printer: str
    state: str  # starting, printing, paused, cancelling, done, cancelled, failed, interrupted
    percent: float | None
    started_by: str
    cancelled_by: str | None = None
    error: str | None = None
    surely_run_line: int = 0
    may_have_run_line: int = 0
    resume_line: int | None = None
    active: bool = False
    """It holds its printer (the service says so: its keys are offered)."""

    @classmethod
    def from_json(cls, value: Mapping[str, Any]) -> JobStatus:
        """Read the service's job (`Job.to_json()`).

        Raises:
            KeyError, TypeError, ValueError: `value` is not a job.
        """
        percent = value.get("percent")
        resume = value.get("resume_line")
        return cls(
            file=str(value["file"]),
            printer=str(value["printer"]),
            state=str(value["state"]),
            percent=None if percent is None else float(percent),
            started_by=str(value.get("started_by") or "?"),
            cancelled_by=value.get("cancelled_by"),
            error=value.get("error"),
            surely_run_line=int(value.get("surely_run_line") or 0),
            may_have_run_line=int(value.get("may_have_run_line") or 0),
            resume_line=None if resume is None else int(resume),
            active=bool(value.get("active")),
        )

    @property
    def resumable(self) -> bool:
        """It ended before its end (cancelled, failed, interrupted) after the printer ran some of it: a resume
        line means something."""
        return self.state in ("cancelled", "failed", "interrupted") and self.surely_run_line > 0


#: The footer's latency figures are of the round trips answered in this many seconds up to the latest: recent
#: enough that a slow G28 stops being the "worst" soon after, long enough to hold a thousand polls.
LATENCY_WINDOW_S = 10.0


@dataclass(frozen=True, slots=True)
class LinkHealth:
    """The footer: how well the link is doing over the last window (the figures `watch` shows; the library's own
    counters are `marlin_aio.LinkStats`)."""

    polls_per_s: float
    latency_median_ms: float | None
    latency_worst_ms: float | None
    readings: int
    timeouts: int
    errors: int
    latency_window_s: float = LATENCY_WINDOW_S  # the span of the latency figures


#: The chart's windows the `w` key steps through (with `--window`'s own, if it is none of these).
WINDOWS_S = (60.0, 600.0, 3600.0, 6 * 3600.0)
_LATENCIES_KEPT = 10_000  # 10 s at 1,000 Hz: a bound on memory whatever the poll rate


class WatchModel:
    """The readings per heater (`HeaterHistory`: up to 12 hours), the chart's window, and the figures `watch`
    shows.

    Args:
        window_s: how much history the chart shows at first; `next_window` steps it through `WINDOWS_S`.
        tolerance_c: a heater within this of its target is "holding".
        rate_window_s: the span the heating rate is measured over (short enough to follow, long enough to
            smooth the 0.01 C steps of M105).
        latency_window_s: the span of the footer's latency figures.
    """

    def __init__(
        self,
        window_s: float = 60.0,
        tolerance_c: float = 2.0,
        rate_window_s: float = 3.0,
        latency_window_s: float = LATENCY_WINDOW_S,
    ) -> None:
        self.window_s = window_s
        self.windows = tuple(sorted({*WINDOWS_S, window_s}))
        self.tolerance_c = tolerance_c
        self.rate_window_s = rate_window_s
        self.latency_window_s = latency_window_s
        self.history: dict[str, HeaterHistory] = {}
        # The last minute of (time, actual, target) per heater key, as read: each history's `raw`.
        self.series: dict[str, deque[Point]] = {}
        self._power: dict[str, int | None] = {}
        self._poll_times: deque[float] = deque()
        self._latencies: deque[tuple[float, float]] = deque(maxlen=_LATENCIES_KEPT)
        self.readings = 0
        self.timeouts = 0
        self.errors = 0
        self.latest_time: float | None = None
        self.latest: TemperatureReading | None = None

    def add(self, reading: TemperatureReading) -> None:
        """Record a reading (any source)."""
        now = reading.monotonic_s
        self.readings += 1
        self.latest_time = now
        self.latest = reading
        for key, heater in reading.temperatures.heaters.items():
            history = self.history.get(key)
            if history is None:
                history = self.history[key] = HeaterHistory()
                self.series[key] = history.raw
            history.add(now, heater.actual, heater.target)
            self._power[key] = heater.power
        if reading.source == "poll":
            self._poll_times.append(now)
            while self._poll_times and self._poll_times[0] < now - 1.0:
                self._poll_times.popleft()

    def add_latency(self, time_s: float, latency_s: float) -> None:
        """Record one command round trip answered at `time_s` (for the footer's median and worst)."""
        self._latencies.append((time_s, latency_s))
        while self._latencies[0][0] < time_s - self.latency_window_s:
            self._latencies.popleft()

    def next_window(self) -> float:
        """Step the chart's window to the next of `windows` (after the longest, the shortest); return it."""
        later = [window for window in self.windows if window > self.window_s]
        self.window_s = later[0] if later else self.windows[0]
        return self.window_s

    def points(self, key: str, start_s: float, column_s: float) -> list[Point]:
        """Heater `key`'s readings from `start_s` on, for a chart `column_s` seconds a column
        (`HeaterHistory.points`)."""
        return self.history[key].points(start_s, column_s)

    def heater_keys(self) -> list[str]:
        """The heaters to show: the hotends first, then the others in the order the printer reports them.

        With several hotends Marlin reports the active one as `T` and then every one as `T0`, `T1`, ...: each of
        those is shown, in tool order where `T` stood, and `T` (a copy of one of them) is not.
        """
        keys = list(self.series)
        tools = sorted((k for k in keys if k[0] == "T" and k[1:].isdigit()), key=lambda k: int(k[1:]))
        if not tools:
            return keys
        return tools + [k for k in keys if k != "T" and k not in tools]

    def target(self, key: str) -> float | None:
        """The target of heater `key` in the newest reading (None: never reported, or reported without one)."""
        series = self.series.get(key)
        return series[-1][2] if series else None

    def status(self, key: str) -> HeaterStatus:
        """The row for one heater."""
        series = self.series[key]
        now, actual, target = series[-1]
        rate = self._rate(series, now)
        power = self._power.get(key)
        power_percent = None if power is None else min(max(power / 127 * 100, 0.0), 100.0)
        if target is None:
            # No target known (a Repetier-style report, and no target line seen): it may be heating to anything, so
            # never "off"; the power (or a rising temperature) says whether it is on, with a "?" for the unknown goal.
            rising = rate is not None and rate > 0.05
            falling = rate is not None and rate < -0.05
            state = "cooling" if falling else "heating?" if rising or (power or 0) > 0 else "unknown"
            eta = None
        elif not target:
            state = "off" if rate is None or rate > -0.05 else "cooling"
            eta = None
        elif abs(actual - target) <= self.tolerance_c:
            state, eta = "holding", 0.0
        elif actual < target:
            state = "heating"
            eta = (target - actual) / rate if rate and rate > 0.01 else None
        else:
            state = "cooling"
            eta = (actual - target) / -rate if rate and rate < -0.01 else None
        return HeaterStatus(key, heater_name(key), actual, target, power_percent, rate, state, eta)

    def _rate(self, series: deque[Point], now: float) -> float | None:
        # Compare with the oldest sample inside the rate window; readings are in time order. From the newest end:
        # the rate window is 3 s of the minute kept, so this reads a twentieth of it.
        start = now - self.rate_window_s
        first = None
        for sample in reversed(series):
            if sample[0] < start:
                break
            first = sample
        if first is None or now - first[0] < 0.5:
            return None
        return (series[-1][1] - first[1]) / (now - first[0])

    def link(self) -> LinkHealth:
        """Footer figures: polls in the last second; the median and worst of the round trips answered in the
        `latency_window_s` up to the latest reading (or round trip), so one slow command ages out."""
        newest = max(self.latest_time or float("-inf"), self._latencies[-1][0] if self._latencies else float("-inf"))
        horizon = newest - self.latency_window_s
        latencies = [latency for answered_s, latency in self._latencies if answered_s >= horizon]
        return LinkHealth(
            polls_per_s=float(len(self._poll_times)),
            latency_median_ms=statistics.median(latencies) * 1000 if latencies else None,
            latency_worst_ms=max(latencies) * 1000 if latencies else None,
            readings=self.readings,
            timeouts=self.timeouts,
            errors=self.errors,
            latency_window_s=self.latency_window_s,
        )


# ------------------------------------------------------------------------------------------- keys


PRESET_KEYS = "123456789"
"""The keys of the presets (the presets file's first nine, in its order; `marlin_aio.farm.presets` reads it)."""
STEP_CELSIUS = 5.0


@dataclass(frozen=True, slots=True)
class SetTargets:
    """Set the active hotend's and/or the bed's target (None: leave it), both already checked."""

    hotend: float | None = None
    bed: float | None = None
    label: str = ""


@dataclass(frozen=True, slots=True)
class TurnOff:
    """Turn every heater the printer reports off."""


@dataclass(frozen=True, slots=True)
class SetFan:
    """Set the part-cooling fan, 0 to 100 percent."""

    percent: float


@dataclass(frozen=True, slots=True)
class SendCommand:
    """Send one G-code line as typed (the library checks it before anything is written)."""

    text: str


@dataclass(frozen=True, slots=True)
class Quit:
    """Leave `watch`."""


@dataclass(frozen=True, slots=True)
class AnswerPrompt:
    """Answer the printer's prompt with its button `index` (0 the first, as `M876 S<index>` counts)."""

    index: int
    label: str


@dataclass(frozen=True, slots=True)
class PauseJob:
    """Pause the served printer's print job (the service stops feeding it; heaters stay as they are)."""


@dataclass(frozen=True, slots=True)
class ResumeJob:
    """Resume the served printer's paused print job."""


@dataclass(frozen=True, slots=True)
class CancelJob:
    """Cancel the served printer's print job (asked, then confirmed with y): the service runs its cancel script."""


Action = SetTargets | TurnOff | SetFan | SendCommand | Quit | AnswerPrompt | PauseJob | ResumeJob | CancelJob


@dataclass(frozen=True, slots=True)
class Notice:
    """What the view shows under the chart: the outcome of the last action (a reply's lines, or an error)."""

    title: str
    lines: tuple[str, ...] = ()
    error: bool = False


#: The G-code commands that set a heater's target (typed on the : line).
_TARGET_CODES = frozenset({"M104", "M109", "M140", "M190", "M141", "M191"})

_ENTER = ("\r", "\n")
_BACKSPACE = ("\x7f", "\x08")
_ESCAPE = "\x1b"
_CLEAR_LINE = "\x15"  # Ctrl-U, as in a shell


@dataclass(frozen=True, slots=True)
class _Prompt:
    what: str  # "hotend", "bed", "fan", "command"
    label: str  # what the input line says before the cursor


_PROMPTS = {
    "h": _Prompt("hotend", "hotend target °C"),
    "b": _Prompt("bed", "bed target °C"),
    "f": _Prompt("fan", "fan %"),
    ":": _Prompt("command", "G-code"),
}


class WatchControls:
    """The keys of the live view as a small state machine: `press(key, model)` returns what to do, if anything.

    Single keys act at once (presets, off, +/-, quit); h, b, f and : open an input line that Enter submits and Esc
    cancels. Nothing here sends anything: a target above its limit, or not a number, becomes an error `notice`
    and no action.

    While a served printer's print job runs (`show_job`), p pauses or resumes it and c asks whether to cancel it:
    only y then cancels, any other key (or a paste) keeps it printing, so one stray key never ends a print.

    Args:
        limits: the highest targets allowed: the same `--max-hotend` and `--max-bed` as `marlin-temp set`.
        keys_enabled: whether key presses can arrive at all (stdin is a terminal); the view says so.
        presets: the presets, in the presets file's order: the first nine get the keys 1-9. Each is checked
            against `limits` when its key is pressed, as a typed target is.
    """

    def __init__(
        self,
        limits: HeaterLimits = DEFAULT_LIMITS,
        *,
        keys_enabled: bool = True,
        presets: tuple[Preset, ...] = DEFAULT_PRESETS,
    ) -> None:
        self.limits = limits
        self.presets = presets[: len(PRESET_KEYS)]
        self.keys_enabled = keys_enabled
        self.notice: Notice | None = None
        self.prompt: str | None = None  # the input line's label while one is open
        self.buffer = ""
        self.stepped = "hotend"  # the heater + and - change: the last one chosen with h or b
        self._prompt: _Prompt | None = None
        # Targets sent but not yet seen in a reading, so + pressed twice quickly steps twice.
        self._wanted: dict[str, float] = {}
        self.heated = False
        """A key (a preset, h, b, +, or a target typed on the : line) set a heater's target above 0: on the way
        out, watch says what is still on."""
        self.job: JobStatus | None = None
        """The served printer's print job (None: no job yet, or not a served printer): `show_job` sets it."""
        self.question: str | None = None
        """The open cancel question, while c waits for its y."""

    # ------------------------------------------------------------------ what the view shows

    def help_items(self) -> list[str]:
        """The key help, one item per key (the view lays them out to fit the width)."""
        if not self.keys_enabled:
            return ["Ctrl-C quits (keys need a terminal on stdin)"]
        if self.question is not None:
            return ["y cancels the print", "any other key goes on"]
        if self._prompt is not None:
            if self._prompt.what == "command":
                return ["Enter sends", "Esc cancels", "one G-code line, e.g. M114"]
            return ["digits, then Enter sets", "Esc cancels"]
        presets = [f"{key} {preset.name}" for key, preset in zip(PRESET_KEYS, self.presets, strict=False)]
        return [
            *self._job_items(),
            "h hotend",
            "b bed",
            "o off",
            f"+/- {STEP_CELSIUS:g}C {self.stepped}",
            *presets,
            "f fan",
            ": command",
            "w window",
            "q quit",
        ]

    def _job_items(self) -> list[str]:
        """The job's keys, first: while it prints or is paused (starting or cancelling, there is nothing to do)."""
        if self.job is None or self.job.state not in ("printing", "paused"):
            return []
        return ["p resume" if self.job.state == "paused" else "p pause", "c cancel print"]

    def show_job(self, job: JobStatus | None) -> None:
        """The job as the service last told it; a cancel question about a job that ended meanwhile is closed."""
        self.job = job
        if self.question is not None and (job is None or not job.active):
            self.question = None
            ended = "" if job is None else f": {job.state}"
            self.notice = Notice(f"the print ended{ended}; nothing cancelled")

    # ------------------------------------------------------------------ keys in

    #: The printer's open prompt (`Printer.prompt`), set by the view each frame: while there is one, its digit keys
    #: answer it, before anything else they mean.
    printer_prompt: Prompt | None = None
    #: What the view says about it (`common.prompts.prompt_text`), or None.
    printer_prompt_text: str | None = None

    def press(self, key: str, model: WatchModel) -> Action | None:
        """Handle one key (a character, or a whole escape sequence) or a paste (`PASTE` and its text); return the
        action it asks for, if any."""
        if self.question is not None:
            return self._answer(key)
        if key.startswith(PASTE):
            return self._paste(key[len(PASTE) :])
        if self._prompt is not None:
            return self._edit(key)
        if self.printer_prompt is not None and (index := answer_index(key, self.printer_prompt)) is not None:
            return AnswerPrompt(index, self.printer_prompt.buttons[index])  # the printer's question wins
        if self.printer_prompt is not None and key.isdigit():
            return None  # not one of its buttons: while the printer asks, a digit is never a preset
        if key == _ESCAPE:
            self.notice = None
            return None
        if len(key) != 1:
            return None  # arrows and other escape sequences mean nothing here
        key = key.lower()
        if key == "q":
            return Quit()
        if key == "w":
            model.next_window()  # what the chart shows, nothing the printer is told
            return None
        if key in _PROMPTS:
            self._open(key)
            return None
        if key == "o":
            self._wanted.clear()
            return TurnOff()
        if key in "pc" and self._job_items():
            return self._job_key(key)
        if key in "+=-_":
            return self._step(STEP_CELSIUS if key in "+=" else -STEP_CELSIUS, model)
        for preset_key, preset in zip(PRESET_KEYS, self.presets, strict=False):
            if key == preset_key:
                return self._targets(preset.hotend_celsius, preset.bed_celsius, preset.name)
        return None

    def _job_key(self, key: str) -> Action | None:
        assert self.job is not None
        if key == "p":
            return ResumeJob() if self.job.state == "paused" else PauseJob()
        self.question = f"cancel the print of {self.job.file}?"  # the key help says y and any other key
        return None

    def _answer(self, key: str) -> Action | None:
        """The key after c: y (either case) cancels; anything else, a paste included, keeps the print going."""
        self.question = None
        if key in ("y", "Y"):
            return CancelJob()
        self.notice = Notice("not cancelled: the print goes on")
        return None

    def _edit(self, key: str) -> Action | None:
        assert self._prompt is not None
        if key == _ESCAPE:
            self._close()
            return None
        if key in _ENTER:
            prompt, text = self._prompt, self.buffer.strip()
            self._close()
            return self._submit(prompt, text)
        if key in _BACKSPACE:
            self.buffer = self.buffer[:-1]
        elif key == _CLEAR_LINE:
            self.buffer = ""
        elif self._prompt.what == "command":
            if len(key) == 1 and key.isprintable():
                self.buffer += key
        elif len(key) == 1 and (key.isdigit() or key == "."):
            self.buffer += key  # a number only: letters typed by mistake must not become a target
        return None

    def _open(self, key: str) -> None:
        """Open the input line of `key` (h, b, f or :)."""
        self._prompt = _PROMPTS[key]
        self.prompt = self._prompt.label
        self.buffer = ""
        if key in "hb":
            self.stepped = self._prompt.what

    def _paste(self, text: str) -> Action | None:
        """Pasted text goes into an open input line, one line of it only; anywhere else it is ignored whole."""
        if self._prompt is None:
            # Only a key that opens an input line may start it (`:M114` typed fast); no key command comes of a paste.
            if text[:1].lower() not in _PROMPTS:
                self.notice = Notice("pasted text is ignored here: press : and paste one G-code line", error=True)
                return None
            self._open(text[0].lower())
            text = text[1:]
        lines = [line for line in text.replace("\r\n", "\n").replace("\r", "\n").split("\n")]
        if len([line for line in lines[:-1] if line.strip()]) > 1 or (len(lines) > 1 and lines[-1].strip()):
            self._close()
            self.notice = Notice("several lines pasted; nothing sent: one line at a time", error=True)
            return None
        action = None
        for key in lines[0]:
            action = self._edit(key) or action
        if len(lines) > 1:  # the pasted line ended with Enter
            action = self._edit("\r")
        return action

    def _close(self) -> None:
        self._prompt = None
        self.prompt = None
        self.buffer = ""

    def _submit(self, prompt: _Prompt, text: str) -> Action | None:
        if not text:
            return None  # Enter on an empty line closes it, like Esc
        if prompt.what == "command":
            self._wanted.clear()  # the line may set targets itself: the readings say what they are now
            return SendCommand(text)
        if prompt.what == "fan":
            try:
                percent = float(text)
            except ValueError:
                percent = -1.0
            if not 0.0 <= percent <= 100.0:
                self.notice = Notice(f"fan speed must be 0 to 100 %, got {text}", error=True)
                return None
            return SetFan(percent)
        if prompt.what == "hotend":
            return self._targets(text, None, "")
        return self._targets(None, text, "")

    def _step(self, delta: float, model: WatchModel) -> Action | None:
        key = "T" if self.stepped == "hotend" else "B"
        if key in model.series and model.target(key) is None and key not in self._wanted:
            # A report without targets: stepping from an unknown target would start from 0 and set 5 C.
            unknown = f"the {self.stepped}'s target is unknown (the printer does not report it)"
            self.notice = Notice(f"{unknown}: press {self.stepped[0]} and type one")
            return None
        base = self._base(key, model)
        if delta < 0 and base <= 0:
            self.notice = Notice(f"the {self.stepped} is already off")
            return None
        new = max(base + delta, 0.0)
        return self._targets(new, None, "") if key == "T" else self._targets(None, new, "")

    def _base(self, key: str, model: WatchModel) -> float:
        reported = model.target(key)
        wanted = self._wanted.get(key)
        if wanted is not None and reported is not None and abs(reported - wanted) < 0.01:
            del self._wanted[key]  # the printer confirmed it: from now on the readings are the truth
            wanted = None
        if wanted is not None:
            return wanted
        return reported or 0.0

    def _targets(self, hotend: float | str | None, bed: float | str | None, label: str) -> Action | None:
        # Both are checked before either is sent: a preset is set whole or not at all.
        checked: dict[str, float] = {}
        for name, raw, limit in (
            ("hotend", hotend, self.limits.hotend),
            ("bed", bed, self.limits.bed),
        ):
            if raw is None:
                continue
            try:
                checked[name] = check_target(name, raw, limit)
            except ValueError as exc:
                hint = f" (raise the limit with --max-{name})" if "above the limit" in str(exc) else ""
                refused = f"{label}: " if label else ""
                self.notice = Notice(f"{refused}{exc}{hint}; nothing sent", error=True)
                return None
        for name, value in checked.items():
            self._wanted["T" if name == "hotend" else "B"] = value
        return SetTargets(hotend=checked.get("hotend"), bed=checked.get("bed"), label=label)

    # ------------------------------------------------------------------ outcomes in

    def finished(self, action: Action, notice: Notice) -> None:
        """Show what became of `action`; a target that failed to go out is no longer counted as wanted."""
        if notice.error and isinstance(action, SetTargets):
            self._wanted.clear()
        if not notice.error:
            if isinstance(action, SetTargets) and (action.hotend or action.bed):
                self.heated = True
            elif isinstance(action, SendCommand) and command_code(action.text) in _TARGET_CODES:
                self.heated = True  # whatever it set: on the way out, the readings say what is on
        self.notice = notice
