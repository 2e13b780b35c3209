"""Temperature readings: every report the printer sends, turned into readings and handed to each subscriber.

Reports come from three places (the `ok T:` of an M105, auto-reports, the wait lines of M109/M190); each becomes a
`TemperatureReading` with its source. Some firmwares send targets on lines of their own (`TargetExtr0:200`); they
fill the targets reports lack. Each subscriber of `readings()` has its own queue, bounded: a reader that falls
behind loses its oldest readings (counted in `dropped`), never a failure, which always gets through.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import time
from collections import deque
from collections.abc import AsyncGenerator, Callable

from marlin_aio.errors import MarlinError
from marlin_aio.events import Event, Ok, TargetTemperature, TemperatureReport
from marlin_aio.temperatures import ReadingSource, TemperatureReading, Temperatures

__all__ = ["TemperatureFeed"]

#: Readings a subscriber may fall behind by before the oldest are dropped: ten seconds of 100 Hz polling.
QUEUE_READINGS = 1000


class _Subscriber:
    """One reader's queue: readings (the oldest dropped past the bound) and at most one failure, which ends it."""

    __slots__ = ("dropped", "failure", "readings", "wakeup")

    def __init__(self) -> None:
        self.readings: deque[TemperatureReading] = deque(maxlen=QUEUE_READINGS)
        self.failure: MarlinError | None = None
        self.wakeup = asyncio.Event()
        self.dropped = 0


class TemperatureFeed:
    """The latest reading, the subscribers of all readings, and the targets learnt from target lines."""

    def __init__(self) -> None:
        self._latest: TemperatureReading | None = None
        # A report nobody subscribed to is kept as its parts; the reading is built when `latest` is read.
        self._unbuilt: tuple[Temperatures, float, float, ReadingSource] | None = None
        self.dropped = 0  # readings dropped because a subscriber fell more than QUEUE_READINGS behind
        self._targets: dict[str, float] = {}  # from Repetier-style target lines, for reports that lack targets
        self._subscribers: list[_Subscriber] = []
        self._callbacks: list[Callable[[TemperatureReading], None]] = []

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
        """Call `callback` with every reading from now on, as it is read; return the function that stops it."""
        self._callbacks.append(callback)

        def remove() -> None:
            with contextlib.suppress(ValueError):
                self._callbacks.remove(callback)

        return remove

    def _arrived(self, temperatures: Temperatures, now: float, source: ReadingSource) -> None:
        if self._subscribers or self._callbacks:
            self.publish(self.reading(temperatures, now, source))
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
        """Make `reading` the latest and hand it to every subscriber."""
        self._latest = reading
        self._unbuilt = None
        for callback in self._callbacks:
            callback(reading)
        for subscriber in self._subscribers:
            if len(subscriber.readings) == QUEUE_READINGS:
                subscriber.dropped += 1
                self.dropped += 1
            subscriber.readings.append(reading)
            subscriber.wakeup.set()

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
