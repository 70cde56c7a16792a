"""Changing a link's conditions while it runs: the command grammar and the schedule file (pure).

Design notes: docs/experiments.md (services/netem/schedule.py).
"""

from __future__ import annotations

import math
import shlex
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from services.netem.model import Impairment, parse_time_s

__all__ = ["ACTIONS", "Command", "Step", "ScheduleError", "parse_command", "parse_schedule", "load_schedule"]

#: Command words (``stats`` only on the control channel).
ACTIONS = ("set", "cut", "restore", "clear", "stats")
_DIRECTIONS = ("both", "up", "down")


class Command(BaseModel):
    """One change of conditions (or ``stats``), validated.

    ``impairment`` is set for ``set`` only, ``duration_s`` for ``cut`` only (None: until restore).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    action: Literal["set", "cut", "restore", "clear", "stats"]
    direction: Literal["both", "up", "down"] = "both"
    impairment: Impairment | None = None
    duration_s: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)

    @model_validator(mode="after")
    def _fields_fit_action(self) -> Command:
        if (self.impairment is not None) != (self.action == "set"):
            raise ValueError("an impairment goes with 'set' and only with it")
        if self.duration_s is not None and self.action != "cut":
            raise ValueError("a duration goes with 'cut' only")
        if self.direction != "both" and self.action != "set":
            raise ValueError("a direction goes with 'set' only")
        return self

    def to_text(self) -> str:
        """The command in the control grammar (docs/experiments.md); ``parse_command(c.to_text()) == c``."""
        if self.action == "set" and self.impairment is not None:
            head = "set" if self.direction == "both" else f"set {self.direction}"
            return f"{head} {shlex.quote(self.impairment.to_text())}"
        if self.action == "cut" and self.duration_s is not None:
            return f"cut {self.duration_s!r}s"
        return self.action


class Step(BaseModel):
    """A :class:`Command` due ``at_s`` seconds after the proxy start, from line ``line``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    at_s: float = Field(ge=0.0, allow_inf_nan=False)
    command: Command
    line: int = Field(default=0, ge=0)

    def to_text(self) -> str:
        return f"at {self.at_s!r}s {self.command.to_text()}"


class ScheduleError(ValueError):
    """A schedule that cannot be read; the message names the file and line."""

    def __init__(self, where: str, line: int, message: str) -> None:
        super().__init__(f"{where}:{line}: {message}")
        self.where, self.line = where, line


def _split(text: str) -> list[str]:
    try:
        return shlex.split(text, comments=True)
    except ValueError as e:  # "No closing quotation"
        raise ValueError(f"{e} in {text.strip()!r}") from None


def _command(tokens: list[str]) -> Command:
    if not tokens:
        raise ValueError("empty command")
    word = tokens[0].lower()
    if word not in ACTIONS:  # a bare impairment spec
        try:
            return Command(action="set", impairment=Impairment.parse(" ".join(tokens)))
        except ValueError as e:
            raise ValueError(f"{_one_line(e)} (a command is {', '.join(ACTIONS)} or an impairment spec)") from None
    rest = tokens[1:]
    if word == "set":
        direction = "both"
        if rest and rest[0].lower() in _DIRECTIONS:
            direction, rest = rest[0].lower(), rest[1:]
        if not rest:
            raise ValueError("set needs an impairment spec ('set none' for a clean link)")
        return Command(action="set", direction=direction, impairment=Impairment.parse(" ".join(rest)))
    if word == "cut":
        if len(rest) > 1:
            raise ValueError(f"cut takes one duration at most, got {' '.join(rest)!r}")
        duration = parse_time_s(rest[0]) if rest else None
        if duration is not None and not (math.isfinite(duration) and duration > 0.0):
            raise ValueError(f"cut duration {rest[0]!r} must be > 0")
        return Command(action="cut", duration_s=duration)
    if rest:
        raise ValueError(f"{word} takes no arguments, got {' '.join(rest)!r}")
    return Command(action=word)


def parse_command(text: str) -> Command:
    """One command of the grammar above, e.g. ``'set "delay 50ms"'`` or ``"cut 5s"``.

    Raises :class:`ValueError` with a one-line message on anything else.
    """
    if not isinstance(text, str):
        raise ValueError(f"a command is text, not {type(text).__name__}")
    try:
        return _command(_split(text))
    except ValueError as e:
        raise ValueError(_one_line(e)) from None


def parse_schedule(text: str, where: str = "<schedule>") -> list[Step]:
    """The steps of a schedule (docs/experiments.md), sorted by time then by line.

    Raises :class:`ScheduleError` naming ``where`` and the line of the first error.
    """
    steps: list[Step] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        try:
            tokens = _split(raw)
            if not tokens:
                continue
            if tokens[0].lower() != "at" or len(tokens) < 3:
                raise ValueError("expected 'at TIME COMMAND', e.g. at 10s cut 5s")
            at_s = parse_time_s(tokens[1])
            command = _command(tokens[2:])
            if command.action == "stats":
                raise ValueError("'stats' is a control-channel command, not a schedule step")
            steps.append(Step(at_s=at_s, command=command, line=number))
        except ValueError as e:
            raise ScheduleError(where, number, _one_line(e)) from None
    return sorted(steps, key=lambda s: (s.at_s, s.line))


def load_schedule(path: str | Path) -> list[Step]:
    """Read and parse a schedule file; unreadable files are :class:`ScheduleError` too (line 0)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ScheduleError(str(path), 0, f"cannot read: {e}") from None
    return parse_schedule(text, str(path))


def _one_line(e: Exception) -> str:
    """pydantic's multi-line messages folded to one line."""
    return " ".join(str(e).split())
