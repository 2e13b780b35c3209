"""The heater limits the CLI checks targets against when it is given none.

Every limit in the CLI is one `marlin_aio.HeaterLimits` (hotend, bed, chamber): `--max-hotend`, `--max-bed` and
`--max-chamber` become one in `options.connect_options`, `ConnectOptions` carries it, and the watch keys, `send`,
`terminal` and the plan of a print check against it. This is the default of all of them: the library's own,
Marlin's default clamps. Kept apart from `connect` so the pure modules (the watch model, the plan of a print) can
take it without the console and the asyncio client.
"""

from __future__ import annotations

from marlin_aio import DEFAULT_MAX_BED_CELSIUS, DEFAULT_MAX_CHAMBER_CELSIUS, DEFAULT_MAX_HOTEND_CELSIUS, HeaterLimits

__all__ = ["DEFAULT_LIMITS"]

#: Marlin's default clamps, as `marlin_aio.Printer` has them: hotend 260 C, bed 140 C, chamber 60 C.
DEFAULT_LIMITS = HeaterLimits(DEFAULT_MAX_HOTEND_CELSIUS, DEFAULT_MAX_BED_CELSIUS, DEFAULT_MAX_CHAMBER_CELSIUS)
