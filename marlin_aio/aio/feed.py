"""Temperature readings: every report the printer sends, turned into readings and handed to each subscriber.

Reports come from three places (the `ok T:` of an M105, auto-reports, the wait lines of M109/M190); each becomes a
`TemperatureReading` with its source. Some firmwares send targets on lines of their own (`TargetExtr0:200`); they
fill the targets reports lack. Each subscriber of `readings()` has its own queue, bounded: a reader that falls
behind loses its oldest readings (counted in `dropped`), never a failure, which always gets through.

No user code runs while the link handles a read (`Link.data_received` calls `on_event` in the middle of its
step): a reading is only queued there. Callbacks (`add_callback`, `Printer.on_reading`) get the readings of one
read in one batch, handed over by `deliver()`, which the link calls once that read's step is done (its bytes
written, its futures resolved): one call per read, not per reading, no loop turn and no task to wake. Readings
published from elsewhere (`publish()`, a served printer's) are delivered by a `loop.call_soon` instead. A callback
that raises is logged once (logger "marlin_aio", WARNING) and counted in `callback_errors` after that; it stays
subscribed, and the other callbacks and the link never notice.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import time
from collections import deque
from collections.abc import AsyncGenerator, Callable

from marlin_aio.errors import MarlinError
from marlin_aio.protocol.events import Event, Ok, TargetTemperature, TemperatureReport
from marlin_aio.protocol.temperatures import ReadingSource, TemperatureReading, Temperatures

__all__ = ["TemperatureFeed"]

#: Readings a subscriber may fall behind by before the oldest are dropped: ten seconds of 100 Hz polling.
QUEUE_READINGS = 1000

_log = logging.getLogger("marlin_aio")


class _Subscriber:
    """One reader's queue: readings (the oldest dropped past the bound) and at most one failure, which ends it."""

    __slots__ = ("dropped", "failure", "readings", "wakeup")

    def __init__(self) -> None:
        self.readings: deque[TemperatureReading] = deque(maxlen=QUEUE_READINGS)
        self.failure: MarlinError | None = None
        self.wakeup = asyncio.Event()
        self.dropped = 0


class _Callback:
    """One callback of `add_callback`: what to call, from which reading on, whether it still wants them, and how
    often it raised."""

    __slots__ = ("active", "call", "errors", "first")

    def __init__(self, call: Callable[[TemperatureReading], None], first: int) -> None:
        self.call = call
        self.first = first  # the number of the first reading it gets: none read before it subscribed
        self.active = True
        self.errors = 0


class TemperatureFeed:
    """The latest reading, the subscribers of all readings, and the targets learnt from target lines."""

    def __init__(self) -> None:
        self._latest: TemperatureReading | None = None
        # A report nobody subscribed to is kept as its parts; the reading is built when `latest` is read.
        self._unbuilt: tuple[Temperatures, float, float, ReadingSource] | None = None
        self.dropped = 0  # readings dropped because a subscriber fell more than QUEUE_READINGS behind
        self._targets: dict[str, float] = {}  # from Repetier-style target lines, for reports that lack targets
        self._subscribers: list[_Subscriber] = []
        self._callbacks: list[_Callback] = []
        self._published = 0  # readings published so far; the last one's number
        # Readings not yet handed to the callbacks (those of one read), the number of the first, and the loop whose
        # `call_soon` will deliver them (None: the link delivers them when the read's step is done).
        self._batch: list[TemperatureReading] = []
        self._batch_first = 0
        self._batch_loop: asyncio.AbstractEventLoop | None = None
        self.callback_errors = 0  # exceptions raised by callbacks, each logged only the first time for its callback

    @property
    def latest(self) -> TemperatureReading | None:
        """The most recent reading, whatever produced it."""
        if self._unbuilt is not None:
            temperatures, now, wall_time_s, source = self._unbuilt
            self._latest = self.reading(temperatures, now, source, wall_time_s)
            self._unbuilt = None
        return self._latest

    def on_event(self, event: Event, now: float) -> None:
        """Turn a received event into a reading (or a target) if it is one."""
        if type(event) is Ok:
            if event.temperatures is not None:
                self._arrived(event.temperatures, now, ReadingSource.POLL)
            return
        match event:
            case TemperatureReport(temperatures=temperatures):
                self._arrived(temperatures, now, ReadingSource.WAIT if temperatures.waiting else ReadingSource.AUTO)
            case TargetTemperature(heater=heater, celsius=celsius):
                self._targets[heater] = celsius

    def add_callback(self, callback: Callable[[TemperatureReading], None]) -> Callable[[], None]:
        """Call `callback` with every reading from now on, soon after it is read (never inside the read handler);
        return the function that stops it (at once: not even readings already read reach it afterwards)."""
        entry = _Callback(callback, self._published + 1)
        self._callbacks.append(entry)

        def remove() -> None:
            entry.active = False
            with contextlib.suppress(ValueError):
                self._callbacks.remove(entry)

        return remove

    def _arrived(self, temperatures: Temperatures, now: float, source: ReadingSource) -> None:
        if self._subscribers or self._callbacks:
            # In the link's read handler, which calls `deliver()` when the read's step is done.
            reading = (
                self.reading(temperatures, now, source)
                if self._targets
                else TemperatureReading(temperatures, now, time.time(), source)
            )
            self._publish(reading, later=False)
        else:
            # No reader: a poller at 100 Hz builds nothing until someone looks at `latest`.
            self._unbuilt = (temperatures, now, time.time(), source)

    def reading(
        self, temperatures: Temperatures, now: float, source: ReadingSource, wall_time_s: float | None = None
    ) -> TemperatureReading:
        """A reading of `temperatures`, with the targets of Repetier-style `TargetExtr0:` lines filled in where the
        report itself carries none."""
        if self._targets:
            heaters = temperatures.heaters
            if any(heater.target is None for heater in heaters.values()):
                filled = {}
                for key, heater in heaters.items():
                    # `T` is the active hotend; these firmwares name hotends by number only.
                    target = self._targets.get(key, self._targets.get("T0") if key == "T" else None)
                    if heater.target is None and target is not None:
                        heater = dataclasses.replace(heater, target=target)
                    filled[key] = heater
                temperatures = Temperatures(filled, temperatures.waiting, temperatures.wait_remaining_s)
        return TemperatureReading(temperatures, now, time.time() if wall_time_s is None else wall_time_s, source)

    def publish(self, reading: TemperatureReading) -> None:
        """Make `reading` the latest, queue it for every subscriber, and have the callbacks called with it soon
        (from a `loop.call_soon`: it calls no user code itself, and must be called on the running loop)."""
        self._publish(reading, later=True)

    def _publish(self, reading: TemperatureReading, *, later: bool) -> None:
        self._latest = reading
        self._unbuilt = None
        self._published += 1
        if self._callbacks:
            if later:
                loop = asyncio.get_running_loop()
                if not self._batch or self._batch_loop is not loop:
                    # The first reading since the last delivery: one call for the batch. (A batch whose loop stopped
                    # before it ran is dropped: its readings belong to a connection that has gone.)
                    self._batch = []
                    self._batch_first = self._published
                    self._batch_loop = loop
                    loop.call_soon(self.deliver)
            elif not self._batch:
                self._batch_first = self._published
                self._batch_loop = None  # delivered by the link when this read's step is done
            self._batch.append(reading)
        for subscriber in self._subscribers:
            if len(subscriber.readings) == QUEUE_READINGS:
                subscriber.dropped += 1
                self.dropped += 1
            subscriber.readings.append(reading)
            subscriber.wakeup.set()

    def deliver(self) -> None:
        """Call every callback with the readings published since the last delivery (none: nothing to do)."""
        if not self._batch:
            return
        batch, self._batch = self._batch, []
        number = self._batch_first
        callbacks = tuple(self._callbacks)  # one added meanwhile gets none of these: they were read before it
        for reading in batch:
            for callback in callbacks:
                # `active`: a callback stopped by itself or another one meanwhile gets nothing more.
                if callback.active and callback.first <= number:
                    try:
                        callback.call(reading)
                    except Exception as exc:  # a callback's bug must not stop the others or the link
                        self._callback_raised(callback, exc)
            number += 1

    def _callback_raised(self, callback: _Callback, exc: Exception) -> None:
        self.callback_errors += 1
        callback.errors += 1
        if callback.errors == 1:
            _log.warning(
                "the reading callback %s raised %r; it is still called with every reading, and its further errors "
                "are counted (Printer.callback_errors), not logged",
                _name_of(callback.call),
                exc,
                exc_info=exc,
            )

    def fail(self, error: MarlinError) -> None:
        """Tell every subscriber that readings end (the printer halted or the link went away)."""
        for subscriber in self._subscribers:
            if subscriber.failure is None:
                subscriber.failure = error
            subscriber.wakeup.set()

    async def readings(self, lost: MarlinError | None) -> AsyncGenerator[TemperatureReading, None]:
        """Yield every reading from now on; raise the failure that ends them (`lost` at once, if given)."""
        subscriber = _Subscriber()
        self._subscribers.append(subscriber)
        try:
            if lost is not None:
                raise lost
            while True:
                while subscriber.readings:
                    yield subscriber.readings.popleft()
                if subscriber.failure is not None:
                    raise subscriber.failure
                subscriber.wakeup.clear()
                await subscriber.wakeup.wait()
        finally:
            self._subscribers.remove(subscriber)


def _name_of(function: Callable[..., object]) -> str:
    """A callable's name for a message: `module.Class.method`, or its repr (a `functools.partial`)."""
    qualname = getattr(function, "__qualname__", None)
    if qualname is None:
        return repr(function)
    module = getattr(function, "__module__", None)
    return f"{module}.{qualname}" if module else str(qualname)
