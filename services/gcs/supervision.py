"""The ground station's supervision of the fleet during a mission: events and time in, decisions out.

Design notes: docs/ground-station.md (services/gcs/supervision.py).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

from protocol.messages import Mode, VehicleState
from services.recording.record import CommandRecord, Incident

__all__ = ["SUPERVISE_PERIOD_S", "FRESH_STATE_S", "START_SETTLE_S", "RESUME_PAUSE_OK_S", "RESUME_PAUSE_FAILED_S",
           "Decisions", "Supervisor", "mission_time"]

#: How often the supervisor looks at liveliness, the own link and failsafe holds, s.
SUPERVISE_PERIOD_S = 0.2
#: A UAV's state counts as heard "now" when received within this many wall seconds.
FRESH_STATE_S = 1.0
#: A hold is looked at only in states received this long after the UAV's Start was acknowledged, s.
START_SETTLE_S = 0.5
#: No new Resume for this long after an accepted one, s (its state must show it flying again).
RESUME_PAUSE_OK_S = 1.0
#: No new Resume for this long after one that failed or was refused, s.
RESUME_PAUSE_FAILED_S = 2.0
#: ... or for this long after one refused for want of a fresh heartbeat, s: one went just ahead of the Resume,
#: so what the board can lack is only its processing; at 0.5 s a UAV resumed half a second after its formation
#: (4 s of trajectory at 8x: the gateway-restart mission's formation error 2.3 m in one CI run)
RESUME_PAUSE_HEARTBEAT_S = 0.1


def mission_time(wall: float, phases: Mapping[str, float], started: float) -> str:
    """``wall`` as "mission t=12.3 s" (from the mission phase's start), or "t=… s" from ``started``.

    >>> mission_time(112.34, {"mission": 100.0}, 90.0), mission_time(95.0, {}, 90.0)
    ('mission t=12.3 s', 't=5.0 s')
    """
    m = phases.get("mission")
    return f"mission t={wall - m:.1f} s" if m is not None else f"t={wall - started:.1f} s"


@dataclass
class Decisions:
    """The outcome of one supervision pass (:meth:`Supervisor.tick`)."""

    incidents: list[Incident] = field(default_factory=list)  # to record, in order
    resume: list[int] = field(default_factory=list)  # UAVs to send a Resume now
    standing_still: bool = False


class Supervisor:
    """The supervision policy's state (docs/ground-station.md) for the mission's ``uavs``; every wall time is
    given by the caller, the own link up since ``now``; ``lost_grace_s`` and ``lost_wait_s`` as
    :class:`services.gcs.mission.MissionOptions`; ``describe`` words a wall time for the incidents."""

    def __init__(self, uavs: Iterable[int], now: float, lost_grace_s: float = 3.0, lost_wait_s: float = 10.0,
                 describe: Callable[[float], str] | None = None, fresh_state_s: float = FRESH_STATE_S):
        self.uavs = tuple(uavs)
        self.lost_grace_s, self.lost_wait_s, self.fresh_state_s = lost_grace_s, lost_wait_s, fresh_state_s
        self.describe = describe or (lambda wall: f"t={wall:.1f} s")
        self.latest: dict[int, VehicleState] = {}  # UAV -> its latest state
        self.rx: dict[int, float] = {}  # UAV -> wall time of its latest state
        self.gone: dict[int, float] = {}  # UAV -> wall time its token went away
        self.lost: dict[int, float] = {}  # UAV -> wall time its token went away, for UAVs declared lost
        self.link_up_since: float | None = now  # None while the own link is down
        self.started: dict[int, float] = {}  # UAV -> wall time its Start was acknowledged
        self.held: dict[int, float] = {}  # UAV -> wall time a mid-mission hold was first seen
        self.resume_after: dict[int, float] = {}  # UAV -> no resume before this wall time
        self.stalled_s = 0.0  # time the fleet stood still, s (sum of the passes' dt)

    # -- events in
    def on_state(self, msg: VehicleState, now: float) -> None:
        """A UAV's state was received at ``now``."""
        self.latest[msg.uav] = msg
        self.rx[msg.uav] = now

    def on_token(self, uav: int, alive: bool, now: float) -> list[Incident]:
        """A UAV's liveliness token appeared (``alive``) or went away at ``now``."""
        out: list[Incident] = []
        if uav not in self.uavs:
            return out
        if alive:
            gone = self.gone.pop(uav, None)
            if gone is not None:
                out.append(Incident(at=now, kind="token-back", uav=uav,
                                    text=f"UAV {uav}'s liveliness token is back after {now - gone:.1f} s"))
            lost = self.lost.pop(uav, None)
            if lost is not None:
                out.append(Incident(at=now, kind="uav-back", uav=uav, text=f"UAV {uav} is back (lost for {now - lost:.1f} s)"))
        elif uav not in self.gone:
            self.gone[uav] = now
            out.append(Incident(at=now, kind="token-gone", uav=uav, text=f"UAV {uav}'s liveliness token went away"))
        return out

    def on_started(self, uavs: Iterable[int], now: float) -> None:
        """The UAVs' Start commands were acknowledged at ``now`` (failsafe holds are looked at from then)."""
        self.started.update({u: now for u in uavs})

    def on_resumed(self, uav: int, rec: CommandRecord, now: float) -> Incident:
        """The Resume sent to ``uav`` ended as ``rec`` at ``now``: when the next may go, and the incident."""
        held_since = self.held.get(uav, now)
        if rec.ok and rec.accepted:
            self.resume_after[uav] = now + RESUME_PAUSE_OK_S
            return Incident(at=now, kind="resume", uav=uav, text=f"UAV {uav} resumed, {now - held_since:.1f} s after "
                                                                 f"its hold was seen ({rec.attempts} tries)")
        # refused for want of a fresh heartbeat (edge.failsafe): the next one is at most 1 / heartbeat_hz away
        pause = RESUME_PAUSE_HEARTBEAT_S if "heartbeat" in (rec.reason or "") else RESUME_PAUSE_FAILED_S
        self.resume_after[uav] = now + pause
        return Incident(at=now, kind="resume-failed", uav=uav,
                        text=f"UAV {uav} not resumed: {rec.reason or 'refused'} ({rec.attempts} tries)")

    # -- one pass
    def tick(self, now: float, dt: float, link_up: bool, resume: bool) -> Decisions:
        """One supervision pass at ``now``, ``dt`` seconds after the previous one: the own link
        (``link_up``), lost UAVs, standing still and (``resume``: the mission phase) failsafe holds."""
        d = Decisions()
        d.incidents += self.check_link(link_up, now)
        d.incidents += self.confirm_losses(now)
        d.standing_still = self.standing_still(now)
        if d.standing_still:
            self.stalled_s += dt
        if resume:
            incidents, d.resume = self.holds(now)
            d.incidents += incidents
        return d

    def check_link(self, up: bool, now: float) -> list[Incident]:
        if up and self.link_up_since is None:
            self.link_up_since = now
            return [Incident(at=now, kind="link-up", text="the ground station reached the gateway again")]
        if not up and self.link_up_since is not None:
            self.link_up_since = None
            return [Incident(at=now, kind="link-down", text="the ground station lost its link to the gateway")]
        return []

    def confirm_losses(self, now: float) -> list[Incident]:
        out: list[Incident] = []
        if self.link_up_since is None:
            return out
        for u, gone in self.gone.items():
            if u not in self.lost and now - max(gone, self.link_up_since) > self.lost_grace_s:
                self.lost[u] = gone
                out.append(Incident(at=now, kind="uav-lost", uav=u,
                                    text=f"UAV {u} lost: no liveliness token since {self.describe(gone)} "
                                         f"({now - gone:.1f} s) while the ground station's link is up"))
        return out

    def standing_still(self, now: float) -> bool:
        """True while the mission cannot progress for a fault: own link down, or a UAV still counted
        (not lost) unheard for a while or holding mid-mission."""
        if self.link_up_since is None:
            return True
        active = [u for u in self.uavs if u not in self.lost]
        if not active:
            return True
        for u in active:
            rx = self.rx.get(u)
            if rx is not None and now - rx > self.fresh_state_s:
                return True
            if u in self.held:
                return True
        return False

    def holds(self, now: float) -> tuple[list[Incident], list[int]]:
        """The UAVs holding mid-mission (their failsafe): ``hold-seen`` incidents for the new ones,
        and those to resume now (heard again, the link up, not resumed just before)."""
        incidents: list[Incident] = []
        ready: list[int] = []
        for u in self.uavs:
            s, rx, started = self.latest.get(u), self.rx.get(u), self.started.get(u)
            if u in self.lost or s is None or rx is None or started is None or rx < started + START_SETTLE_S:
                continue
            held = s.armed and s.mode == Mode.HOLD and s.progress < 1.0
            if not held:
                self.held.pop(u, None)
                continue
            if u not in self.held:
                self.held[u] = now
                incidents.append(Incident(at=now, kind="hold-seen", uav=u,
                                          text=f"UAV {u} holds mid-mission at {s.progress:.0%} of its trajectory "
                                               f"(its failsafe; the ground station did not command it)"))
            if (now - rx <= self.fresh_state_s and self.link_up_since is not None
                    and now >= self.resume_after.get(u, 0.0)):
                ready.append(u)
        return incidents, ready

    # -- questions
    def fleet_done(self, finished: Callable[[int, VehicleState | None], bool], now: float) -> bool:
        """Every UAV still counted (not lost) is ``finished``; lost ones are waited for ``lost_wait_s``
        after they went away, unless every UAV is lost (then never: the wait's own timeout ends it)."""
        active = [u for u in self.uavs if u not in self.lost]
        if not active or not all(finished(u, self.latest.get(u)) for u in active):
            return False
        return not self.lost or now - max(self.lost.values()) > self.lost_wait_s
