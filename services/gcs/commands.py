"""Commands from the ground station to a UAV: tries with exponential back-off, every outcome recorded.

Design notes: docs/ground-station.md (services/gcs/commands.py).
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import cast

from protocol import keys
from protocol.bus import Bus
from protocol.messages import CommandAck
from services.recording.record import CommandRecord

__all__ = ["RetryPolicy", "CommandIds", "send", "not_sent", "start_margin"]


@dataclass(frozen=True)
class RetryPolicy:
    """How a command is tried: ``attempts`` tries of ``timeout_s`` each, back-off from ``backoff_s``."""

    attempts: int = 4
    timeout_s: float = 2.0
    backoff_s: float = 0.25

    def __post_init__(self) -> None:
        if self.attempts < 1 or not self.timeout_s > 0 or not self.backoff_s >= 0:
            raise ValueError(f"need attempts >= 1, timeout_s > 0 and backoff_s >= 0, got {self}")

    def pauses(self) -> list[float]:
        """The pause after each failed try, s (doubling).

        >>> RetryPolicy().pauses()
        [0.25, 0.5, 1.0, 2.0]
        """
        return [self.backoff_s * 2**k for k in range(self.attempts)]


class CommandIds:
    """Command ids, 1, 2, 3, ... (thread-safe: commands go out from several threads at once)."""

    def __init__(self) -> None:
        self._next = itertools.count(1)
        self._lock = threading.Lock()

    def next(self) -> int:
        with self._lock:
            return next(self._next)


def not_sent(cmd, reason: str) -> CommandRecord:
    """The record of a command that was not sent (``reason`` says why, prefixed "not sent: ")."""
    return CommandRecord(uav=cmd.uav, kind=cmd.kind, cmd_id=cmd.cmd_id, ok=False, accepted=False,
                         reason=f"not sent: {reason}", attempts=0, elapsed_s=0.0)


def send(bus: Bus, cmd, policy: RetryPolicy, sleep: Callable[[float], None] = time.sleep, signer=None) -> CommandRecord:
    """Send one command to ``cmd.uav`` with retries and back-off; a refusal is final (not retried).

    Returns the :class:`CommandRecord`: ``ok`` when a :class:`CommandAck` came back (``accepted``
    and ``reason`` are its own), else the last try's error after ``policy.attempts`` tries;
    ``ack_s`` holds the round trip of every answered try.
    """
    t0 = time.monotonic()
    acks, reason = [], ""
    for attempt, backoff in enumerate(policy.pauses(), 1):
        key = keys.cmd(bus.fleet, cmd.uav)
        payload = cmd if signer is None else signer.sign(cmd, key)
        reply = bus.request(key, payload, expect=CommandAck, timeout=policy.timeout_s)
        if reply.ok:
            acks.append(reply.elapsed_s)
            ack = cast(CommandAck, reply.message)  # expect=CommandAck: an ok reply is one
            return CommandRecord(uav=cmd.uav, kind=cmd.kind, cmd_id=cmd.cmd_id, ok=True, accepted=ack.accepted,
                                 reason=ack.reason, attempts=attempt, elapsed_s=time.monotonic() - t0, ack_s=acks)
        reason = reply.error
        sleep(backoff)
    return CommandRecord(uav=cmd.uav, kind=cmd.kind, cmd_id=cmd.cmd_id, ok=False, accepted=False, reason=reason,
                         attempts=policy.attempts, elapsed_s=time.monotonic() - t0, ack_s=acks)


def start_margin(commands: Iterable[CommandRecord], least_s: float, most_s: float = 30.0) -> float:
    """How far ahead the common start time ``t0`` is set, s.

    The Start commands go out to all UAVs at once, and each must arrive before ``t0`` or that UAV
    begins behind the others (and formation keeping pulls them back toward it): twice the slowest
    acknowledgement so far, at least ``least_s``, at most ``most_s`` (docs/ground-station.md).

    >>> start_margin([CommandRecord(uav=1, kind="takeoff", cmd_id=1, ok=True, accepted=True, elapsed_s=1.5,
    ...                             ack_s=[1.5])], least_s=2.0)
    3.0
    """
    slowest = max((a for c in commands for a in c.ack_s), default=0.0)
    return min(most_s, max(least_s, 2.0 * slowest))
