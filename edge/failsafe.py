"""The board's failsafe policy: lost ground station, escalation, low battery, resume rules.

Design notes: docs/edge.md (edge/failsafe.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from protocol.messages import EventKind

ACTIONS = ("hold", "land", "rtl")
ESCALATIONS = ("rtl", "land", "none")
#: how much an action ends the flight: a failsafe never steps down (rtl -> hold)
_SEVERITY = {"hold": 0, "rtl": 1, "land": 2}


@dataclass(frozen=True)
class FailsafeOptions:
    timeout_s: float = 5.0
    action: str = "hold"
    escalate_after_s: float = 30.0
    escalate_action: str = "rtl"
    battery_low: float = 0.2
    battery_critical: float = 0.1
    retry_s: float = 1.0  # the least time between two attempts of a failed action

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise ValueError(f"failsafe action {self.action!r}: one of {ACTIONS}")
        if self.escalate_action not in ESCALATIONS:
            raise ValueError(f"escalation {self.escalate_action!r}: one of {ESCALATIONS}")
        if not (self.timeout_s > 0 and self.escalate_after_s >= 0):
            raise ValueError("failsafe timeout must be > 0 s and the escalation time >= 0 s")
        if not self.retry_s > 0:
            raise ValueError("failsafe retry period must be > 0 s")
        if not 0.0 <= self.battery_critical <= self.battery_low <= 1.0:
            raise ValueError("need 0 <= battery_critical <= battery_low <= 1")


@dataclass(frozen=True)
class Decision:
    """An action to take now, why (``gcs`` or ``battery``), an event kind and its text."""

    action: str
    reason: str
    kind: EventKind
    text: str


#: what to try after an action failed (ArduPilot: an RTL that cannot be flown becomes a land)
FALLBACK = {"hold": "hold", "rtl": "land", "land": "land"}


@dataclass(frozen=True)
class Failure:
    """A failsafe action the vehicle did not take: what failed, why, what is tried next and when."""

    action: str
    error: str
    next_action: str
    retry_at: float
    attempts: int  # failed attempts of this failsafe so far

    @property
    def text(self) -> str:
        then = "retrying" if self.next_action == self.action else f"trying {self.next_action} instead"
        return f"{self.action} failed: {self.error}; {then} (attempt {self.attempts + 1})"


class FailsafePolicy:
    """Failsafe state of one board; the board calls :meth:`step` every tick (times are wall seconds)."""

    def __init__(self, options: FailsafeOptions | None = None):
        self.opt = options or FailsafeOptions()
        self.active = False  # a GCS failsafe is on (cleared by an accepted Resume)
        self.since: float | None = None
        self.escalated = False
        self.battery: str | None = None  # "low" / "critical" once the battery failsafe fired
        self.current: str | None = None  # the last action ordered
        self.pending: Failure | None = None  # an action that failed and is to be tried again
        self.failures = 0  # failed attempts since the last action that was done

    def failed(self, action: str, error: str, now: float) -> Failure:
        """The vehicle did not take ``action`` (``error``): what to try next (:data:`FALLBACK`), not before
        ``now + retry_s``; the policy keeps it until :meth:`retry` hands it out or :meth:`done` clears it."""
        self.failures += 1
        nxt = FALLBACK[action]
        if self.current is None or _SEVERITY[nxt] >= _SEVERITY[self.current]:
            self.current = nxt
        self.pending = Failure(action, error, nxt, now + self.opt.retry_s, self.failures)
        return self.pending

    def retry(self, now: float, airborne: bool) -> Decision | None:
        """The failed action to try again now, or None (none pending, too soon, or the UAV is down)."""
        f = self.pending
        if f is None:
            return None
        if not airborne:  # on the ground (landed or disarmed): nothing left to do
            self.pending = None
            return None
        if now < f.retry_at:
            return None
        self.pending = None
        return Decision(f.next_action, "retry", EventKind.FAILSAFE_RETRY,
                        f"{f.action} failed {f.attempts} time(s) ({f.error}): {f.next_action} again"
                        if f.next_action == f.action else
                        f"{f.action} failed ({f.error}): {f.next_action} instead")

    def done(self) -> int:
        """The vehicle took the last action: returns the failed attempts before it (0: first time)."""
        n, self.failures, self.pending = self.failures, 0, None
        return n

    def _order(self, action: str, reason: str, kind: EventKind, text: str) -> Decision | None:
        if self.current is not None and _SEVERITY[action] < _SEVERITY[self.current]:
            return None  # never step down: a UAV landing stays landing
        self.current, self.pending = action, None  # a new order supersedes a retry
        return Decision(action, reason, kind, text)

    def step(self, now: float, last_heartbeat: float | None, flying: bool, battery: float,
             returning: bool = False) -> Decision | None:
        """What to do now, or None. ``returning``: the UAV is already coming home (RTL): only the
        critical battery (land) still applies, a lost ground station does not stop it."""
        if not (flying or returning):
            return None
        o = self.opt
        if battery <= o.battery_critical and self.battery != "critical":
            self.battery = "critical"
            return self._order("land", "battery", EventKind.BATTERY_FAILSAFE,
                               f"battery at {battery:.0%} (critical {o.battery_critical:.0%}): land")
        if returning:
            return None
        if battery <= o.battery_low and self.battery is None:
            self.battery = "low"
            return self._order("rtl", "battery", EventKind.BATTERY_FAILSAFE,
                               f"battery at {battery:.0%} (low {o.battery_low:.0%}): return to launch")
        if last_heartbeat is None:
            return None  # never heard a ground station: nothing to lose
        silent = now - last_heartbeat
        if not self.active:
            if silent <= o.timeout_s:
                return None
            self.active, self.since, self.escalated = True, now, False
            return self._order(o.action, "gcs", EventKind.FAILSAFE,
                               f"no ground-station heartbeat for {silent:.1f} s: {o.action}")
        held = now - (now if self.since is None else self.since)
        if (not self.escalated and o.escalate_action != "none" and o.action == "hold"
                and held >= o.escalate_after_s and silent > o.timeout_s):
            self.escalated = True
            return self._order(o.escalate_action, "gcs", EventKind.FAILSAFE_ESCALATED,
                               f"no ground-station heartbeat for {silent:.1f} s, held {held:.1f} s: "
                               f"{o.escalate_action}")
        return None

    def may_resume(self, now: float, last_heartbeat: float | None) -> str | None:
        """None if a Resume may be applied now, else why not."""
        if self.battery is not None:
            return f"battery failsafe ({self.battery}): not resumed"
        if not self.active:
            return None
        if (last_heartbeat is None or (self.since is not None and last_heartbeat <= self.since)
                or now - last_heartbeat > self.opt.timeout_s):
            return "failsafe: no fresh ground-station heartbeat yet"
        return None

    def resumed(self) -> float | None:
        """The Resume was applied: the GCS failsafe ends; returns when it began."""
        since = self.since
        self.active, self.since, self.escalated, self.current = False, None, False, None
        self.pending, self.failures = None, 0
        return since
