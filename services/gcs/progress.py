"""Live mission progress in the terminal: a bar per UAV, formation error, link figures.

:func:`render` is pure (state in, lines out); :class:`LiveDisplay` redraws those lines in place
on a terminal (ANSI cursor-up), or prints them every few seconds when the output is a pipe.
"""

from __future__ import annotations

import logging
import math
import statistics
import sys
import threading
import time
from typing import IO

import numpy as np

from edge.geometry import formation
from protocol.messages import Mode, VehicleState
from protocol.textsafe import printable
from services.gcs.figures import HEADING_MIN_SPEED


def bar(fraction: float, width: int = 24) -> str:
    fraction = min(1.0, max(0.0, fraction))
    full = int(round(fraction * width))
    return "█" * full + "·" * (width - full)


class HeadingHold:
    """The formation heading ψ of the live line, taken as the report takes it (:mod:`services.gcs.figures`):
    that of the fleet's mean horizontal velocity, held while the fleet is slower than
    :data:`~services.gcs.figures.HEADING_MIN_SPEED` (hovering at a capture point or the goal); 0 before
    any motion."""

    def __init__(self) -> None:
        self.yaw = 0.0

    def update(self, vel: np.ndarray) -> float:
        if math.hypot(float(vel[0]), float(vel[1])) > HEADING_MIN_SPEED:
            self.yaw = math.atan2(float(vel[1]), float(vel[0]))
        return self.yaw


def formation_rms(states: dict[int, VehicleState], offsets: dict[int, tuple[float, float, float]],
                  heading: HeadingHold | None = None) -> float | None:
    """RMS shape error (P6) of the latest states of the UAVs flying the formation (MISSION or HOLD: on the
    ground, taking off or landing there is no formation to keep, and a landed one has lost its heights:
    the last line said 1.4-2.0 m where the report, mission phase only, said 0.12); ``heading`` keeps ψ
    across slow moments (one per display)."""
    ids = [u for u in states if u in offsets and states[u].mode in (Mode.MISSION, Mode.HOLD)]
    if len(ids) < 2:
        return None
    vel = np.mean([states[u].vel for u in ids], axis=0)
    yaw = (heading or HeadingHold()).update(vel)
    return formation.formation_error({u: states[u].pos for u in ids}, None, yaw, offsets)


def render(phase: str, states: dict[int, VehicleState], uavs: tuple[int, ...], ages_ms: list[float],
           reports: int, captures_planned: int, offsets: dict[int, tuple[float, float, float]], elapsed_s: float,
           notes: dict[int, str] | None = None, heading: HeadingHold | None = None) -> list[str]:
    """The live block; ``notes`` adds a word per UAV (``LOST``, ``silent 3.2 s``) after its line; ``heading``
    holds the formation heading from one call to the next (:class:`HeadingHold`)."""
    lines = [f"mission {elapsed_s:6.1f} s  phase: {phase}"]
    notes = notes or {}
    for u in uavs:
        s = states.get(u)
        note = f"  [{notes[u]}]" if notes.get(u) else ""
        if s is None:
            lines.append(f"  UAV {u}  (no telemetry yet){note}")
            continue
        lines.append(f"  UAV {u}  {bar(s.progress)} {100 * s.progress:5.1f} %  {s.mode.value:<8} "
                     f"z {s.pos[2]:5.1f} m  {math.hypot(*s.vel):4.1f} m/s  captures {s.captures}{note}")
    err = formation_rms(states, offsets, heading)
    age = f"{statistics.median(ages_ms):.1f} ms" if ages_ms else "-"
    lines.append(f"  formation RMS error {'-' if err is None else f'{err:.2f} m'}   telemetry age p50 {age}   "
                 f"defect reports {reports}/{captures_planned}")
    return lines


class LiveDisplay:
    def __init__(self, stream: IO[str] = sys.stdout, period_s: float = 0.25, pipe_period_s: float = 5.0):
        self.stream = stream
        self.tty = stream.isatty()
        self.period = period_s if self.tty else pipe_period_s
        self._last = 0.0
        self._drawn = 0
        self._lines: list[str] = []
        self._lock = threading.Lock()

    def message(self, text: str) -> None:
        """Print a line above the live block (log messages), then redraw the block; control characters in
        ``text`` (which may quote another node) are printed as escapes, so only the display moves the cursor."""
        with self._lock:
            if self.tty and self._drawn:
                self.stream.write(f"\x1b[{self._drawn}F\x1b[J")
            self.stream.write(printable(text, keep="\n") + "\n")
            if self.tty and self._lines:
                for line in self._lines:
                    self.stream.write("\x1b[2K" + line + "\n")
            else:
                self._drawn = 0
            self.stream.flush()

    def handler(self) -> logging.Handler:
        """A logging handler that writes through :meth:`message`."""
        display = self

        class _Handler(logging.Handler):
            def emit(self, record: logging.LogRecord) -> None:
                display.message(self.format(record))

        return _Handler()

    def update(self, lines: list[str], force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last < self.period:
            return
        with self._lock:
            self._last = now
            if self.tty and self._drawn:
                self.stream.write(f"\x1b[{self._drawn}F")
            for line in lines:
                self.stream.write(("\x1b[2K" if self.tty else "") + line + "\n")
            self._drawn = len(lines)
            self._lines = list(lines)
            self.stream.flush()
