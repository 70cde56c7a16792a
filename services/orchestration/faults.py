"""Scripted fault injection during a run: the ``--fault`` grammar, its schedule, and the injector.

Design notes: docs/experiments.md (services/orchestration/faults.py).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

from services.gcs.resilience import NOT_INJECTED
from services.netem.model import parse_time_s
from services.orchestration.topology import Links, link_ends

Action = Literal["kill", "cut", "partition"]
ACTIONS = ("kill", "cut", "partition")
#: the actions noted when a fault ends (``MissionRunner.note_fault``)
END_ACTION = {"kill": "restart", "cut": "restore", "partition": "heal"}
KILLABLE = ("gateway", "planner", "detector")


#: the latest a fault may begin or end, s (a day: longer than any mission; ``1e999s`` is refused, not scheduled
#: for a time that never comes)
MAX_FAULT_S = 86_400.0


def parse_duration(tok: str, what: str) -> float:
    """``500ms``, ``20s``, ``1.5min`` → seconds; a unit is required (the netem parser's units); at most
    :data:`MAX_FAULT_S` (so never infinite or NaN)."""
    try:
        value = parse_time_s(tok)
    except ValueError as exc:
        raise ValueError(f"{what} {tok!r}: {exc}") from None
    if not 0.0 <= value <= MAX_FAULT_S:  # also false for NaN
        raise ValueError(f"{what} {tok!r}: must be between 0 s and {MAX_FAULT_S:.0f} s")
    return value


@dataclass(frozen=True)
class Fault:
    """One ``--fault`` item as written (not yet checked against a network)."""

    at_s: float
    action: Action
    target: str
    duration_s: float | None
    text: str


def parse_fault(text: str) -> Fault:
    """Parse ``AT ACTION TARGET [for D]``; ValueError naming the bad token."""
    toks = text.split()
    if len(toks) not in (3, 5):
        raise ValueError(f"fault {text!r}: expected 'AT ACTION TARGET [for D]', e.g. '20s kill gateway for 3s'")
    at = parse_duration(toks[0], f"fault {text!r}: AT")
    action = toks[1]
    if action not in ACTIONS:
        raise ValueError(f"fault {text!r}: action {action!r} is not one of {', '.join(ACTIONS)}")
    duration = None
    if len(toks) == 5:
        if toks[3] != "for":
            raise ValueError(f"fault {text!r}: expected 'for D' after the target, got {toks[3]!r}")
        duration = parse_duration(toks[4], f"fault {text!r}: D")
        if duration <= 0.0:
            raise ValueError(f"fault {text!r}: D {toks[4]!r} must be > 0")
    return Fault(at, action, toks[2], duration, " ".join(toks))  # type: ignore[arg-type]


@dataclass(frozen=True)
class Resolved:
    """A fault checked against a run: the service it kills or the links whose proxies it cuts."""

    fault: Fault
    service: str | None = None
    links: tuple[str, ...] = ()

    @property
    def end_s(self) -> float | None:
        f = self.fault
        return None if f.duration_s is None else f.at_s + f.duration_s


def resolve(fault: Fault, links: Links) -> Resolved:
    """Check the target of ``fault`` against the run; ValueError naming the target if it is not there."""
    t, what = fault.target, f"fault {fault.text!r}: target"
    if fault.action == "kill":
        if t in KILLABLE:
            return Resolved(fault, service=t)
        if t.startswith("uav"):
            return Resolved(fault, service=f"uav{links.uav(t, what)}")
        raise ValueError(f"{what} {t!r}: kill takes gateway, uavN, planner or detector")
    if fault.action == "cut":
        if t == "uplinks":
            return Resolved(fault, links=tuple(links.edges))
        if t in ("skynet", "all") or link_ends(t) is not None:
            raise ValueError(f"{what} {t!r}: cut takes uplinks, uavN, " + ", ".join(links.services)
                             + " (use 'partition' for SkyNet links)")
        try:
            return Resolved(fault, links=tuple(links.resolve(t)))
        except ValueError as e:
            raise ValueError(f"{what}: {e}") from None
    # partition
    if links.uavs < 2:
        raise ValueError(f"{what} {t!r}: a SkyNet partition needs at least 2 UAVs")
    if t == "skynet":
        return Resolved(fault, links=tuple(links.skynet))
    ends = link_ends(t)
    if ends is not None:
        try:
            return Resolved(fault, links=tuple(links.resolve(t)))
        except ValueError as e:
            raise ValueError(f"{what}: {e}") from None
    if t.startswith("uav"):
        n = links.uav(t, what)
        return Resolved(fault, links=tuple(name for name in links.skynet if n in link_ends(name)))
    raise ValueError(f"{what} {t!r}: partition takes skynet, uavI-uavJ or uavN")


@dataclass(frozen=True, order=True)
class Step:
    """One action at ``t_s`` after the origin: a fault's beginning or its end."""

    t_s: float
    order: int  # ends before beginnings at the same instant, then in the order given
    begin: bool = field(compare=False)
    item: Resolved = field(compare=False)

    @property
    def action(self) -> str:
        a = self.item.fault.action
        return a if self.begin else END_ACTION[a]


def schedule(items: Iterable[Resolved]) -> list[Step]:
    """The steps of all faults in time order. Two kills of one service that overlap (or a kill
    of a service already killed for good) are refused with a ValueError."""
    items = list(items)
    down: dict[str, Resolved] = {}
    for r in sorted((r for r in items if r.service), key=lambda r: r.fault.at_s):
        prev = down.get(r.service)
        if prev is not None and (prev.end_s is None or prev.end_s > r.fault.at_s):
            raise ValueError(f"fault {r.fault.text!r}: {r.service} is still down from {prev.fault.text!r}")
        down[r.service] = r
    steps = []
    for k, r in enumerate(items):
        steps.append(Step(r.fault.at_s, 1000 + k, True, r))
        if r.end_s is not None:
            steps.append(Step(r.end_s, k, False, r))
    return sorted(steps)


def plan_faults(texts: Iterable[str], links: Links) -> list[Resolved]:
    """Parse, resolve and schedule-check ``--fault`` items (ValueError on the first bad one)."""
    out = [resolve(parse_fault(t), links) for t in texts]
    schedule(out)
    return out


def cut_links(items: Iterable[Resolved]) -> set[str]:
    """The links whose proxies some fault cuts (the launcher puts clean proxies there)."""
    return {link for r in items if r.fault.action in ("cut", "partition") for link in r.links}


# ----------------------------------------------------------------------------- the shell
class Target(Protocol):
    """What the injector acts on (the launcher's :class:`~services.orchestration.launcher.Network`)."""

    def kill(self, name: str) -> None: ...

    def restart(self, name: str) -> float: ...  # seconds until it is up again

    def link_proxies(self, link: str) -> list[Any]: ...  # objects with cut() and restore()


class FaultInjector:
    """Runs a fault schedule against a :class:`Target` on its own thread.

    ``start(origin)`` with a wall time (``skynet up``), or ``attach(runner)`` then ``start()``:
    the origin is then the runner's ``record.phases["mission"]`` once it appears, and injection
    stops when ``record.phases["done"]`` appears. Each action and each end goes to ``note(action,
    target, text)`` (the runner's ``note_fault`` when attached) and to :attr:`ledger`.
    """

    def __init__(self, target: Target, items: list[Resolved], log: logging.Logger | None = None,
                 note: Callable[[str, str, str], None] | None = None) -> None:
        self.target = target
        self.steps = schedule(items)
        self.log = log or logging.getLogger("skynet.faults")
        self.note = note
        self.runner: Any = None
        self.ledger: list[tuple[float, str, str, str]] = []
        self._origin: float | None = None
        self._steps_run = 0
        self._cuts: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fault-injector", daemon=True)

    def attach(self, runner: Any) -> None:
        """The ground station's hook (``run_mission(on_runner=...)``)."""
        self.runner = runner
        if self.note is None:
            self.note = runner.note_fault

    def start(self, origin: float | None = None) -> FaultInjector:
        self._origin = origin
        self._thread.start()
        return self

    def cancel(self) -> None:
        """Inject nothing more from now on (does not wait; see :meth:`stop`)."""
        self._stop.set()

    def stop(self, timeout: float = 30.0) -> None:
        """Stop injecting and wait for the thread (a restart in progress finishes, or fails once the
        process group is stopping)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def finish(self) -> list[str]:
        """Stop injecting (the mission is over) and note every scheduled fault that never began as
        ``not-injected`` (its text as written); their texts. A step still running is not counted as missed."""
        self.stop()
        started = self._steps_run + (1 if self._thread.is_alive() else 0)
        missed = [s.item.fault for s in self.steps[started:] if s.begin]
        for f in missed:
            self._record(NOT_INJECTED, f.target, f.text)
        return [f.text for f in missed]

    def done(self) -> bool:
        return not self._thread.is_alive()

    # -- thread
    def _phase(self, name: str) -> float | None:
        if self.runner is None:
            return None
        return self.runner.record.phases.get(name)

    def _wait_until(self, t: float) -> bool:
        """Sleep until wall time ``t``; False if stopped or the mission ended first."""
        while True:
            if self._stop.is_set() or self._phase("done") is not None:
                return False
            left = t - time.time()
            if left <= 0.0:
                return True
            self._stop.wait(min(left, 0.1))

    def _run(self) -> None:
        while self._origin is None:
            self._origin = self._phase("mission")
            if self._origin is None and (self._stop.wait(0.05) or self._phase("done") is not None):
                return
        for step in self.steps:
            if not self._wait_until(self._origin + step.t_s):
                return
            try:
                text = self._act(step)
            except Exception as e:  # a failed action is reported, the schedule goes on
                self.log.exception("fault %r failed", step.item.fault.text)
                text = f"{step.item.fault.text}: failed: {e}"
            self._record(step.action, step.item.fault.target, text)
            self._steps_run += 1

    def _record(self, action: str, target: str, text: str) -> None:
        self.ledger.append((time.time(), action, target, text))
        if self.note is not None:  # (the ground station's runner logs what it is told)
            self.note(action, target, text)
        else:
            self.log.warning("fault: %s %s (%s)", action, target, text)

    def _act(self, step: Step) -> str:
        r, f = step.item, step.item.fault
        if r.service is not None:
            if step.begin:
                self.target.kill(r.service)
                return f.text
            up = self.target.restart(r.service)
            return f"{r.service} restarted after {f.duration_s:g}s down; up again {up:.2f}s later"
        changed = []
        for link in r.links:
            n = self._cuts.get(link, 0)
            self._cuts[link] = n + 1 if step.begin else max(0, n - 1)
            if (step.begin and n == 0) or (not step.begin and n == 1):
                for p in self.target.link_proxies(link):
                    p.cut() if step.begin else p.restore()
                changed.append(link)
        verb = "cut" if step.begin else "restored"
        return f"{f.text}: {verb} {', '.join(changed) or 'nothing (still cut by another fault)'}"
