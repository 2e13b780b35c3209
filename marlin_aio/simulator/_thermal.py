"""The heater model of the simulated printer: first-order thermal masses under a simple controller.

Each heater is a lumped heat capacity with a heating element and a loss to ambient proportional to the temperature
difference, in units that need no Joules: `heating_rate_cps` is how fast it warms at full power near ambient and
`loss_per_s` is the share of the excess over ambient lost per second. The controller is a proportional band with
feed-forward (the steady-state power for the target, known exactly from the model), so a heater runs at full power
until it is close, then approaches the target exponentially without overshoot and holds it with no offset.

Time is discrete: the model only changes on a fixed grid of `STEP_US` (0.1 simulated seconds), so a run does not
depend on how often the caller asks, and a temperature read between grid points is the last sample, like a real
firmware's sensor. Each step uses the exact solution for constant power over the step, which keeps it stable and
cheap; heaters that are off, or settled at their target, skip whole stretches in one closed-form jump so an idle
printer costs nothing.

`Heaters` is one board's set of them (its hotends, and its bed and chamber when it has them), brought up to a given
time together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["BED", "CHAMBER", "HOTEND", "STEP_US", "Heater", "HeaterSpec", "Heaters"]

#: The fixed integration step, in simulated microseconds.
STEP_US = 100_000
_STEP_S = STEP_US / 1_000_000

#: Closer than this to the target (and not saturated), a heater counts as settled and stops being integrated.
_SETTLED_CELSIUS = 0.0005


@dataclass(frozen=True, slots=True)
class HeaterSpec:
    """The physical constants and controller gain of one kind of heater."""

    heating_rate_cps: float
    """Temperature rise per second at full power, at ambient temperature."""
    loss_per_s: float
    """Share of the excess over ambient lost per second (1 / thermal time constant)."""
    gain_per_celsius: float
    """Proportional gain: extra power share per degree below the target."""
    max_target_celsius: float
    """Targets above this are clamped silently, like Marlin's MAXTEMP minus overshoot."""


# Hotend: ~3.4 C/s at first like the captured board, ~18 % power to hold 200 C, 25 -> 200 C (within 1 C) in ~70 s.
HOTEND = HeaterSpec(heating_rate_cps=3.4, loss_per_s=0.0035, gain_per_celsius=0.04, max_target_celsius=260.0)
# Bed: ~0.45 C/s at first, ~23 % power to hold 60 C, 25 -> 60 C in ~90 s; can still reach its 140 C limit.
BED = HeaterSpec(heating_rate_cps=0.45, loss_per_s=0.003, gain_per_celsius=0.2, max_target_celsius=140.0)
# Heated chamber: slow, a few minutes to 40 C.
CHAMBER = HeaterSpec(heating_rate_cps=0.1, loss_per_s=0.002, gain_per_celsius=0.3, max_target_celsius=60.0)


class Heater:
    """One heater: its temperature, target and power, advanced on the fixed grid."""

    __slots__ = (
        "_decay",
        "_settled",
        "ambient_celsius",
        "celsius",
        "integrated_steps",
        "power",
        "spec",
        "target_celsius",
    )

    def __init__(self, spec: HeaterSpec, ambient_celsius: float) -> None:
        self.spec = spec
        self.ambient_celsius = ambient_celsius
        self.celsius = ambient_celsius
        self.target_celsius = 0.0
        self.power = 0.0
        """Heater drive as a share of full power, 0.0 to 1.0."""
        self._decay = math.exp(-spec.loss_per_s * _STEP_S)
        self._settled = True
        self.integrated_steps = 0
        """Grid steps integrated one by one so far (closed-form jumps and settled stretches cost none): the
        model's work, which tests can count instead of timing it."""

    @property
    def power_127(self) -> int:
        """Power on Marlin's soft-PWM scale (0-127), as M105 shows it after `@:`."""
        return int(self.power * 127 + 0.5)

    def set_target(self, celsius: float) -> float:
        """Set the target, clamped to 0 .. the spec's maximum; return the value actually set."""
        celsius = min(max(celsius, 0.0), self.spec.max_target_celsius)
        if celsius != self.target_celsius:
            self.target_celsius = celsius
            self._settled = False
        return celsius

    def steps_to_change(self, celsius: float) -> int:
        """How many grid steps at least pass before the temperature can have moved by `celsius` (at least 1).

        A bound, so a wait can sleep until its condition could possibly change instead of checking every step.
        """
        spec = self.spec
        excess = max(self.celsius, self.target_celsius) - self.ambient_celsius
        fastest = max(spec.heating_rate_cps / spec.loss_per_s, excess) * (1.0 - self._decay)
        return max(1, int(celsius / fastest))

    def advance(self, steps: int) -> None:
        """Run `steps` grid steps."""
        if steps <= 0:
            return
        ambient = self.ambient_celsius
        if self.target_celsius <= ambient:
            # Off (or a target it can only reach by cooling, which needs no power): plain exponential cooling,
            # jumped in closed form however long it was.
            self.power = 0.0
            if self.celsius != ambient:
                self.celsius = ambient + (self.celsius - ambient) * self._decay**steps
                if abs(self.celsius - ambient) < _SETTLED_CELSIUS:
                    self.celsius = ambient
            return
        if self._settled:
            return
        spec = self.spec
        target = self.target_celsius
        decay = self._decay
        full_rise = spec.heating_rate_cps / spec.loss_per_s  # equilibrium excess over ambient at full power
        feed_forward = (target - ambient) / full_rise
        gain = spec.gain_per_celsius
        celsius = self.celsius
        power = self.power
        done = 0
        for _ in range(steps):
            done += 1
            error = target - celsius
            power = feed_forward + gain * error
            power = 0.0 if power < 0.0 else 1.0 if power > 1.0 else power
            equilibrium = ambient + full_rise * power
            celsius = equilibrium + (celsius - equilibrium) * decay
            if 0.0 < power < 1.0 and abs(target - celsius) < _SETTLED_CELSIUS:
                # Holding: from here on the feed-forward alone keeps it exactly at the target.
                celsius = target
                power = min(max(feed_forward, 0.0), 1.0)
                self._settled = True
                break
        self.integrated_steps += done
        self.celsius = celsius
        self.power = power


class Heaters:
    """A board's heaters: its hotends, and its bed and chamber when it has them, advanced together."""

    __slots__ = ("_step", "bed", "by_name", "chamber", "hotends")

    def __init__(
        self, extruders: int, *, has_bed: bool, has_chamber: bool, ambient_celsius: float, now_us: int
    ) -> None:
        """The heaters of a board built so, all at `ambient_celsius` and off, at the simulated time `now_us`."""
        self.hotends = [Heater(HOTEND, ambient_celsius) for _ in range(extruders)]
        self.bed = Heater(BED, ambient_celsius) if has_bed else None
        self.chamber = Heater(CHAMBER, ambient_celsius) if has_chamber else None
        self.by_name: dict[str, Heater] = {f"T{i}": heater for i, heater in enumerate(self.hotends)}
        """Each heater by the name M105 gives it: "T0", "T1", ... "B" (bed) and "C" (chamber)."""
        if self.bed is not None:
            self.by_name["B"] = self.bed
        if self.chamber is not None:
            self.by_name["C"] = self.chamber
        self._step = now_us // STEP_US

    @property
    def integrated_steps(self) -> int:
        """Grid steps integrated one by one so far, over all the heaters (`Heater.integrated_steps`)."""
        return sum(heater.integrated_steps for heater in self.by_name.values())

    def sync(self, now_us: int) -> None:
        """Bring every heater up to the simulated time `now_us` (to the last grid point at or before it)."""
        step = now_us // STEP_US
        steps = step - self._step
        if steps > 0:
            self._step = step
            for heater in self.by_name.values():
                heater.advance(steps)

    def switch_off(self) -> None:
        """Every target to 0, as kill() and a reset leave them (the temperatures themselves carry on)."""
        for heater in self.by_name.values():
            heater.set_target(0.0)
