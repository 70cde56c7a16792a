"""Run the missions of an experiment, one ``skynet mission`` process at a time, never hanging.

Design notes: docs/experiments.md (services/experiment/runner.py).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .grid import Run
from .metrics import run_metrics

__all__ = ["RunResult", "descendants", "run_all", "run_mission"]


@dataclass
class RunResult:
    run: Run
    status: str  # "ok", "no-report", "hung"
    exit: int | None
    wall_s: float
    out: str
    command: list[str]
    metrics: dict[str, float | None] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"cell": self.run.cell.as_dict(), "repeat": self.run.repeat, "seed": self.run.seed,
                "name": self.run.name, "status": self.status, "exit": self.exit, "wall_s": self.wall_s,
                "out": self.out, "command": self.command, "metrics": self.metrics}


def _stat(pid: int | str) -> list[str] | None:
    """Fields 3.. of /proc/PID/stat (after the command name, which may hold spaces), or None."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()


def _proc_start(pid: int) -> str | None:
    """Start time of a process (field 22 of /proc/PID/stat), to tell a reused pid apart."""
    fields = _stat(pid)
    return None if fields is None else fields[19]


def descendants(pid: int) -> list[tuple[int, str | None]]:
    """Every process below ``pid`` (children, grandchildren, ...) as (pid, start time), from /proc
    (each process's stat read once)."""
    children: dict[int, list[tuple[int, str]]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or (fields := _stat(entry.name)) is None:
            continue
        children.setdefault(int(fields[1]), []).append((int(entry.name), fields[19]))
    out: list[tuple[int, str | None]] = []
    todo = [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child[0])
    return out


def _stop(proc: subprocess.Popen, grace_s: float) -> None:
    """SIGINT, then SIGKILL for the process and everything it started that is still there."""
    family = descendants(proc.pid)
    try:
        proc.send_signal(signal.SIGINT)
        proc.wait(grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    for pid, started in family:
        if started is not None and _proc_start(pid) == started:  # still the same process
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def run_mission(run: Run, command: Sequence[str], out: Path, timeout_s: float, grace_s: float = 20.0,
                cwd: str | None = None) -> RunResult:
    """One run: the mission's output goes to ``out/mission.log``; its report is ``out/report.json``."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    status = "ok"
    with open(out / "mission.log", "w") as log:
        proc = subprocess.Popen(list(command), stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                cwd=cwd, start_new_session=True)  # Ctrl-C of the experiment is ours to pass on
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            status = "hung"
            _stop(proc, grace_s)
        except BaseException:  # Ctrl-C: stop this run cleanly, then let the caller see it
            _stop(proc, grace_s)
            raise
    wall = time.monotonic() - t0
    report = None
    path = out / "report.json"
    if path.exists():
        try:
            report = json.loads(path.read_text())
        except (OSError, ValueError):
            report = None
    if status == "ok" and report is None:
        status = "no-report"
    return RunResult(run, status, proc.returncode, wall, str(out), list(command),
                     run_metrics(report, wall, hung=status == "hung"))


def run_all(runs: Sequence[Run], command_of: Callable[[Run, Path], list[str]], out: Path, timeout_s: float,
            on_result: Callable[[RunResult, int, int], None] | None = None, grace_s: float = 20.0,
            cwd: str | None = None) -> list[RunResult]:
    """Every run in order, each into ``out/runs/<run name>``; ``on_result(result, i, n)`` after each."""
    results = []
    for i, run in enumerate(runs):
        folder = out / "runs" / run.name
        res = run_mission(run, command_of(run, folder), folder, timeout_s, grace_s, cwd)
        results.append(res)
        if on_result is not None:
            on_result(res, i, len(runs))
    return results
