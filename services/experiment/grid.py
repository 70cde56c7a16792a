"""The experiment grid: lists of link conditions -> cells -> seeded runs -> mission commands (pure).

Design notes: docs/experiments.md (services/experiment/grid.py).
"""

from __future__ import annotations

import itertools
import math
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass

__all__ = ["Cell", "Run", "check_links", "expand", "impair_spec", "mission_command", "parse_list", "parse_recovery", "plan"]

ONSET_S = 2.0


def parse_list(text: str, name: str, *, lo: float = 0.0, hi: float | None = None, integer: bool = False
               ) -> tuple[float, ...]:
    """``"0,5,20"`` -> ``(0.0, 5.0, 20.0)``: finite numbers in ``[lo, hi]``, no duplicates, at least one;
    ValueError with a one-line message naming ``name`` (the option)."""
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"{name}: expected a comma-separated list of numbers, got {text!r}")
    out: list[float] = []
    for item in text.split(","):
        item = item.strip()
        try:
            v = float(item)
        except ValueError:
            raise ValueError(f"{name}: {item!r} is not a number (in {text!r})") from None
        if not math.isfinite(v) or v < lo or (hi is not None and v > hi):
            bounds = f"in {lo:g}..{hi:g}" if hi is not None else f">= {lo:g}"
            raise ValueError(f"{name}: {item!r} must be a finite number {bounds}")
        if integer and v != int(v):
            raise ValueError(f"{name}: {item!r} must be a whole number")
        if v in out:
            raise ValueError(f"{name}: {item!r} is listed twice")
        out.append(v)
    return tuple(out)


def parse_recovery(text: str) -> tuple[bool, ...]:
    """``"on,off"`` -> ``(True, False)``."""
    words = {"on": True, "off": False}
    items = [w.strip().lower() for w in str(text).split(",")]
    if not items or any(w not in words for w in items):
        raise ValueError(f"--recovery: expected on, off or on,off, got {text!r}")
    if len(set(items)) != len(items):
        raise ValueError(f"--recovery: {text!r} lists a value twice")
    return tuple(words[w] for w in items)


def check_links(text: str, uavs: int) -> str:
    """The ``--links`` target (``all/udp``, ``uplinks``, ``uav2/udp``, ...), checked with the launcher's
    own grammar (:func:`services.orchestration.topology.parse_impair`) for a fleet of ``uavs``."""
    from services.orchestration.topology import Links, parse_impair

    text = str(text).strip()
    try:
        parse_impair([impair_spec(Cell(1, 0, 0), text)], Links(uavs))
    except ValueError as e:
        raise ValueError(f"--links {text!r}: {e}") from None
    return text


@dataclass(frozen=True, order=True)
class Cell:
    """One link condition: random loss (%), one-way delay and jitter (ms), imagery recovery."""

    loss_pct: float
    delay_ms: float
    jitter_ms: float
    recovery: bool = True

    @property
    def name(self) -> str:
        """Folder-safe id, e.g. ``loss5-delay50-jitter0-rec``."""
        return (f"loss{self.loss_pct:g}-delay{self.delay_ms:g}-jitter{self.jitter_ms:g}-"
                f"{'rec' if self.recovery else 'norec'}")

    @property
    def label(self) -> str:
        return (f"loss {self.loss_pct:g}% delay {self.delay_ms:g} ms jitter {self.jitter_ms:g} ms, "
                f"recovery {'on' if self.recovery else 'off'}")

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Run:
    """One mission of the experiment: a cell, its repeat index and its seed."""

    cell: Cell
    repeat: int
    seed: int

    @property
    def name(self) -> str:
        return f"{self.cell.name}-r{self.repeat}"


def expand(loss: Sequence[float], delay: Sequence[float], jitter: Sequence[float] = (0.0,),
           recovery: Sequence[bool] = (True,)) -> list[Cell]:
    """Every combination, loss varying fastest after recovery (so with/without pairs sit together).

    >>> [c.name for c in expand([0, 5], [50])]
    ['loss0-delay50-jitter0-rec', 'loss5-delay50-jitter0-rec']
    >>> len(expand([0, 5, 20, 40], [0, 50, 200], [0, 20], [True, False]))
    48
    """
    for name, values in (("loss", loss), ("delay", delay), ("jitter", jitter), ("recovery", recovery)):
        if len(values) == 0:
            raise ValueError(f"{name}: the grid needs at least one value")
    return [Cell(float(l), float(d), float(j), bool(r))
            for d, j, l, r in itertools.product(delay, jitter, loss, recovery)]


def plan(cells: Sequence[Cell], repeat: int = 1, seed: int = 0) -> list[Run]:
    """The runs, repeat-major (every cell once, then every cell again), repeat ``k`` seeded ``seed + k``.

    Repeat-major order means a stopped experiment still has every cell at least once.
    """
    if isinstance(repeat, bool) or not isinstance(repeat, int) or repeat < 1:
        raise ValueError(f"--repeat must be an int >= 1, got {repeat!r}")
    return [Run(c, k, seed + k) for k in range(repeat) for c in cells]


def impair_spec(cell: Cell, links: str = "all/udp", onset_s: float = ONSET_S) -> str:
    """The launcher's ``--impair`` value of a cell.

    >>> impair_spec(Cell(20, 200, 0))
    'all/udp=after 2s delay 200ms loss 20%'
    >>> impair_spec(Cell(0, 0, 0), "uav2")
    'uav2=after 2s'
    """
    terms = [f"after {onset_s:g}s"]
    if cell.delay_ms:
        terms.append(f"delay {cell.delay_ms:g}ms")
    if cell.jitter_ms:
        terms.append(f"jitter {cell.jitter_ms:g}ms")
    if cell.loss_pct:
        terms.append(f"loss {cell.loss_pct:g}%")
    return f"{links}=" + " ".join(terms)


def mission_command(run: Run, out: str, *, links: str = "all/udp", speed: float = 6.0, uavs: int = 3,
                    scenario: str | None = None, insecure: bool = False, python: str = sys.executable,
                    mission: Sequence[str] = ()) -> list[str]:
    """The ``skynet mission`` command line of one run (``python -m services.cli mission ...``); ``mission``: more
    of its options, the same in every run (the detector's method, the vehicle)."""
    cmd = [python, "-m", "services.cli", "mission", "--quiet", "--speed", f"{speed:g}", "--uavs", str(uavs),
           "--seed", str(run.seed), "--out", out, "--impair", impair_spec(run.cell, links), *mission]
    if not run.cell.recovery:
        cmd.append("--no-recovery")
    if scenario:
        cmd += ["--scenario", scenario]
    if insecure:
        cmd.append("--insecure")
    return cmd
