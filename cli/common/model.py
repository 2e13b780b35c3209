"""What `watch` knows: a rolling window of readings per heater, the figures derived from it, and the keys.

Pure data, no I/O and no rich: the live view, the plain-line output and the tests all read the same numbers.
Readings arrive about every 10 ms, so adding one must be cheap: it appends to a deque and trims the front.

`WatchControls` turns key presses into actions (set targets, fan, a G-code line, quit) without touching the
printer: every target is checked here, with the limits `set` uses, so a refused one becomes a notice in the view
and never an action. `watch/command.py` performs the actions and hands their outcome back as a `Notice`.

Over 400 lines because the view's data and the keys' meaning are read together: `WatchControls` checks a target
against what `WatchModel` shows (the heaters the printer has), and both are pure, so one test file covers them.
"""

from __future__ import annotations

import statistics
from collections import deque
from dataclasses import dataclass

from marlin_aio import HeaterLimits, TemperatureReading
from marlin_aio.protocol import DEFAULT_LIMITS, HEATER_NAMES, Prompt, check_target, command_code, heater_name

from .keys import PASTE
from .prompts import answer_index

__all__ = [
    "HEATER_NAMES",
    "PRESETS",
    "STEP_CELSIUS",
    "Action",
    "AnswerPrompt",
    "HeaterStatus",
    "LinkHealth",
    "Notice",
    "Preset",
    "Quit",
    "SendCommand",
    "SetFan",
    "SetTargets",
    "TurnOff",
    "WatchControls",
    "WatchModel",
    "heater_name",
]


@dataclass(frozen=True, slots=True)
class HeaterStatus:
    """One heater's row: actual, target, power, rate and state, with an estimated time to target."""

    key: str
    name: str
    actual: float
    target: float | None
    power_percent: float | None
    rate_c_per_s: float | None
    state: str  # "heating", "cooling", "holding", "off"
    eta_s: float | None


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


class WatchModel:
    """Readings of the last `window_s` seconds, per heater, and the figures `watch` shows.

    Args:
        window_s: how much history the chart shows.
        tolerance_c: a heater within this of its target is "holding".
        rate_window_s: the span the heating rate is measured over (short enough to follow, long enough to
            smooth the 0.01 C steps of M105).
    """

    def __init__(self, window_s: float = 60.0, tolerance_c: float = 2.0, rate_window_s: float = 3.0) -> None:
        self.window_s = window_s
        self.tolerance_c = tolerance_c
        self.rate_window_s = rate_window_s
        # time, actual, target per heater key: parallel tuples in one deque keep appends cheap
        self.series: dict[str, deque[tuple[float, float, float | None]]] = {}
        self._power: dict[str, int | None] = {}
        self._poll_times: deque[float] = deque()
        self._latencies: deque[tuple[float, float]] = deque()
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
        horizon = now - self.window_s
        for key, heater in reading.temperatures.heaters.items():
            series = self.series.get(key)
            if series is None:
                series = self.series[key] = deque()
            series.append((now, heater.actual, heater.target))
            while series and series[0][0] < horizon:
                series.popleft()
            self._power[key] = heater.power
        if reading.source == "poll":
            self._poll_times.append(now)
            while self._poll_times and self._poll_times[0] < now - 1.0:
                self._poll_times.popleft()

    def add_latency(self, time_s: float, latency_s: float) -> None:
        """Record one command round trip (for the footer's median and worst)."""
        self._latencies.append((time_s, latency_s))
        while self._latencies and self._latencies[0][0] < time_s - self.window_s:
            self._latencies.popleft()

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
        if not target:
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

    def _rate(self, series: deque[tuple[float, float, float | None]], now: float) -> float | None:
        # Compare with the oldest sample inside the rate window; readings are in time order.
        start = now - self.rate_window_s
        first = None
        for sample in series:
            if sample[0] >= start:
                first = sample
                break
        if first is None or now - first[0] < 0.5:
            return None
        return (series[-1][1] - first[1]) / (now - first[0])

    def link(self) -> LinkHealth:
        """Footer figures: polls in the last second, latency median and worst over the window."""
        latencies = [latency for _, latency in self._latencies]
        return LinkHealth(
            polls_per_s=float(len(self._poll_times)),
            latency_median_ms=statistics.median(latencies) * 1000 if latencies else None,
            latency_worst_ms=max(latencies) * 1000 if latencies else None,
            readings=self.readings,
            timeouts=self.timeouts,
            errors=self.errors,
        )


# ------------------------------------------------------------------------------------------- keys


@dataclass(frozen=True, slots=True)
class Preset:
    """A material's usual targets, set with one key."""

    key: str
    name: str
    hotend_celsius: float
    bed_celsius: float


PRESETS = (Preset("1", "PLA", 200.0, 60.0), Preset("2", "PETG", 240.0, 80.0))
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


Action = SetTargets | TurnOff | SetFan | SendCommand | Quit | AnswerPrompt


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

    Args:
        limits: the highest targets allowed: the same `--max-hotend` and `--max-bed` as `marlin-temp set`.
        keys_enabled: whether key presses can arrive at all (stdin is a terminal); the view says so.
    """

    def __init__(self, limits: HeaterLimits = DEFAULT_LIMITS, *, keys_enabled: bool = True) -> None:
        self.limits = limits
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

    # ------------------------------------------------------------------ what the view shows

    def help_items(self) -> list[str]:
        """The key help, one item per key (the view lays them out to fit the width)."""
        if not self.keys_enabled:
            return ["Ctrl-C quits (keys need a terminal on stdin)"]
        if self._prompt is not None:
            if self._prompt.what == "command":
                return ["Enter sends", "Esc cancels", "one G-code line, e.g. M114"]
            return ["digits, then Enter sets", "Esc cancels"]
        presets = [f"{p.key} {p.name}" for p in PRESETS]
        return [
            "h hotend",
            "b bed",
            "o off",
            f"+/- {STEP_CELSIUS:g}C {self.stepped}",
            *presets,
            "f fan",
            ": command",
            "q quit",
        ]

    # ------------------------------------------------------------------ keys in

    #: The printer's open prompt (`Printer.prompt`), set by the view each frame: while there is one, its digit keys
    #: answer it, before anything else they mean.
    printer_prompt: Prompt | None = None
    #: What the view says about it (`common.prompts.prompt_text`), or None.
    printer_prompt_text: str | None = None

    def press(self, key: str, model: WatchModel) -> Action | None:
        """Handle one key (a character, or a whole escape sequence) or a paste (`PASTE` and its text); return the
        action it asks for, if any."""
        if key.startswith(PASTE):
            return self._paste(key[len(PASTE) :])
        if self._prompt is not None:
            return self._edit(key)
        if self.printer_prompt is not None and (index := answer_index(key, self.printer_prompt)) is not None:
            return AnswerPrompt(index, self.printer_prompt.buttons[index])  # the printer's question wins
        if key == _ESCAPE:
            self.notice = None
            return None
        if len(key) != 1:
            return None  # arrows and other escape sequences mean nothing here
        key = key.lower()
        if key == "q":
            return Quit()
        if key in _PROMPTS:
            self._open(key)
            return None
        if key == "o":
            self._wanted.clear()
            return TurnOff()
        if key in "+=-_":
            return self._step(STEP_CELSIUS if key in "+=" else -STEP_CELSIUS, model)
        for preset in PRESETS:
            if key == preset.key:
                return self._targets(preset.hotend_celsius, preset.bed_celsius, preset.name)
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
