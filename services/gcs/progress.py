"""Live mission progress in the terminal: a bar per UAV, formation error, link figures.

Design notes: docs/ground-station.md (services/gcs/progress.py).
"""

from __future__ import annotations

import logging
import math
import statistics
import sys
import threading
import time
from typing import IO

from edge.geometry import formation
from protocol.messages import Mode, VehicleState
from protocol.textsafe import printable


def bar(fraction: float, width: int = 24) -> str:
    fraction = min(1.0, max(0.0, fraction))
    full = int(round(fraction * width))
    return "█" * full + "·" * (width - full)


class HeadingHold:
    """The formation error's memory from one redraw to the next: a :class:`edge.geometry.formation.ShapeErrorMeter`
    (the rule of the report and the web page), made for the offsets of the first call."""

    def __init__(self) -> None:
        self.meter: formation.ShapeErrorMeter | None = None
        self._t = -math.inf

    def error(self, t: float, positions: dict, offsets: dict) -> float | None:
        """The newest error known after the fleet's positions at ``t`` (that of half a heading window ago)."""
        if self.meter is None or self.meter.offsets != offsets:
            self.meter, self._t = formation.ShapeErrorMeter(offsets), -math.inf
        if t > self._t:  # else no newer state since the last redraw
            self._t = t
            self.meter.add(t, positions)
        return self.meter.latest


def flying_formation(states: dict[int, VehicleState], offsets: dict) -> list[int]:
    """The UAVs that fly the formation now (MISSION or HOLD: on the ground, taking off or landing there is no
    formation to keep); none unless at least two."""
    ids = [u for u in sorted(states) if u in offsets and states[u].mode in (Mode.MISSION, Mode.HOLD)]
    return ids if len(ids) >= 2 else []


def formation_rms(states: dict[int, VehicleState], offsets: dict[int, tuple[float, float, float]],
                  heading: HeadingHold | None = None) -> float | None:
    """The formation error (:class:`edge.geometry.formation.ShapeErrorMeter`) of the latest states of the UAVs flying
    the formation, at the newest state's time; ``heading`` keeps the heading across redraws (one per
    display); None with fewer than two flying or before the fleet has moved."""
    ids = flying_formation(states, offsets)
    if not ids:
        return None
    return (heading or HeadingHold()).error(max(states[u].t for u in ids), {u: states[u].pos for u in ids}, offsets)


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
