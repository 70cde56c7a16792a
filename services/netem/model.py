"""What a link does to packets: the impairment description and the seeded per-packet decisions.

Design notes: docs/experiments.md (services/netem/model.py).
"""

from __future__ import annotations

import heapq
import math
import re
import threading
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

__all__ = ["DROP_REASONS", "GilbertElliott", "Impairment", "Counters", "Impairer", "DEFAULT_MSS", "parse_time_s"]

#: Reasons a datagram is dropped, the keys of :attr:`Counters.dropped`.
DROP_REASONS = ("loss", "outage", "queue")

#: TCP segment payload assumed when counting lost segments of a stream chunk (Ethernet MSS).
DEFAULT_MSS = 1448

Probability = Field(default=0.0, ge=0.0, le=1.0, allow_inf_nan=False)


class GilbertElliott(BaseModel):
    """Gilbert–Elliott burst loss in netem's ``gemodel`` parameters (Salsano et al. 2010): per packet
    ``p`` Good → Bad, ``r`` Bad → Good; loss ``loss_bad`` (netem's ``1-h``) and ``loss_good`` (``1-k``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    p: float = Field(ge=0.0, le=1.0, allow_inf_nan=False)
    r: float = Field(ge=0.0, le=1.0, allow_inf_nan=False)
    loss_bad: float = Field(default=1.0, ge=0.0, le=1.0, allow_inf_nan=False)
    loss_good: float = Field(default=0.0, ge=0.0, le=1.0, allow_inf_nan=False)

    @model_validator(mode="after")
    def _moves(self) -> GilbertElliott:
        if self.p + self.r <= 0.0:
            raise ValueError("gemodel: p and r cannot both be 0 (the chain would never move)")
        return self

    @property
    def mean_loss(self) -> float:
        """Stationary loss rate ``(p (1-h) + r (1-k)) / (p + r)``."""
        return (self.p * self.loss_bad + self.r * self.loss_good) / (self.p + self.r)


class Impairment(BaseModel):
    """What one direction of a link does to traffic; validated, immutable.

    Times in milliseconds, probabilities as fractions in [0, 1], rate in kilobits per second
    (1 kbit = 1000 bit; 0 = unlimited). See docs/experiments.md for the exact semantics and
    :meth:`parse` for the netem-like string form.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    delay_ms: float = Field(default=0.0, ge=0.0, le=3.6e6, allow_inf_nan=False)
    jitter_ms: float = Field(default=0.0, ge=0.0, le=3.6e6, allow_inf_nan=False)
    distribution: Literal["uniform", "normal"] = "uniform"
    loss: float = Probability
    loss_correlation: float = Field(default=0.0, ge=0.0, lt=1.0, allow_inf_nan=False)
    gilbert_elliott: GilbertElliott | None = None
    duplicate: float = Probability
    reorder: float = Probability
    reorder_ms: float = Field(default=10.0, gt=0.0, le=3.6e6, allow_inf_nan=False)
    rate_kbps: float = Field(default=0.0, ge=0.0, le=1e9, allow_inf_nan=False)
    limit: int = Field(default=1000, ge=0, le=10_000_000, description="packets held at most; 0 = unlimited")
    outages: tuple[tuple[float, float], ...] = ()
    rto_ms: float = Field(default=200.0, gt=0.0, le=3.6e6, allow_inf_nan=False)
    after_s: float = Field(default=0.0, ge=0.0, le=1e7, allow_inf_nan=False,
                           description="onset: impair only from this long after the origin (not outages)")
    fifo: bool = True

    @model_validator(mode="after")
    def _check(self) -> Impairment:
        if self.gilbert_elliott is not None and (self.loss > 0.0 or self.loss_correlation > 0.0):
            raise ValueError("give either loss [correlation] or gilbert_elliott, not both")
        return self

    @field_validator("outages", mode="after")
    @classmethod
    def _sorted_outages(cls, v: tuple[tuple[float, float], ...]) -> tuple[tuple[float, float], ...]:
        for start, duration in v:
            if not (math.isfinite(start) and math.isfinite(duration)) or start < 0.0 or duration <= 0.0:
                raise ValueError(f"outage ({start}, {duration}): need start_s >= 0 and duration_s > 0, finite")
        return tuple(sorted(v))

    # ------------------------------------------------------------------ construction
    @classmethod
    def parse(cls, text: str) -> Impairment:
        """Parse a netem-like string, e.g. ``"delay 50ms jitter 10ms loss 2% rate 2mbit"``.

        An empty string (or ``"none"``) is the null impairment. Errors are :class:`ValueError`
        naming the offending token.

        >>> Impairment.parse("delay 50ms 10ms loss 2%").jitter_ms
        10.0
        >>> Impairment.parse("rate 2mbit").rate_kbps
        2000.0
        """
        if not isinstance(text, str):
            raise ValueError(f"impairment text must be a string, not {type(text).__name__}")
        tokens = text.split()
        if tokens in ([], ["none"]):
            return cls()
        out: dict[str, Any] = {}
        outages: list[tuple[float, float]] = []
        i = 0
        kw = ""

        def take(what: str) -> str:
            nonlocal i
            if i >= len(tokens):
                raise ValueError(f"{kw!r} needs {what}, got end of text")
            i += 1
            return tokens[i - 1]

        def peek(pred) -> bool:
            return i < len(tokens) and pred(tokens[i])

        while i < len(tokens):
            kw = tokens[i].lower()
            i += 1
            if kw in _SINGLE:
                name, what, read = _SINGLE[kw]
                out[name] = read(take(what))
            elif kw == "delay":
                out["delay_ms"] = _time_ms(take("a time"))
                if peek(_is_time):
                    out["jitter_ms"] = _time_ms(take("a time"))
            elif kw == "distribution":
                name = take("uniform or normal")
                if name.lower() not in ("uniform", "normal"):
                    raise ValueError(f"distribution {name!r}: use uniform or normal")
                out["distribution"] = name.lower()
            elif kw == "loss":
                if peek(lambda t: t.lower() == "random"):
                    i += 1
                if peek(lambda t: t.lower() == "gemodel"):
                    i += 1
                    p = _percent(take("a percentage p"))
                    ge: dict[str, float] = {"p": p, "r": 1.0 - p}
                    for name in ("r", "loss_bad", "loss_good"):
                        if not peek(_is_percent):
                            break
                        ge[name] = _percent(take("a percentage"))
                    out["gilbert_elliott"] = ge
                else:
                    out["loss"] = _percent(take("a percentage"))
                    if peek(_is_percent):
                        out["loss_correlation"] = _percent(take("a percentage"))
            elif kw == "reorder":
                out["reorder"] = _percent(take("a percentage"))
                if peek(_is_time):
                    out["reorder_ms"] = _time_ms(take("a time"))
            elif kw == "limit":
                tok = take("a packet count")
                if not re.fullmatch(r"\d+", tok):
                    raise ValueError(f"limit {tok!r}: need a whole number of packets")
                out["limit"] = int(tok)
            elif kw == "outage":
                start = _time_ms(take("a start time")) / 1000.0
                duration = _time_ms(take("a duration")) / 1000.0
                outages.append((start, duration))
            elif kw == "unordered":
                out["fifo"] = False
            else:
                raise ValueError(f"unknown keyword {tokens[i - 1]!r} in impairment {text!r}")
        if outages:
            out["outages"] = tuple(outages)
        return cls.model_validate(out)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Impairment:
        """Build from a mapping of field names (e.g. a TOML/JSON table); outages as pairs."""
        if not isinstance(data, dict):
            raise ValueError(f"impairment dict expected, got {type(data).__name__}")
        return cls.model_validate(data)

    @classmethod
    def coerce(cls, spec: Impairment | str | dict[str, Any] | None) -> Impairment:
        """Accept an :class:`Impairment`, a netem-like string, a dict, or None (no impairment)."""
        if spec is None:
            return cls()
        if isinstance(spec, Impairment):
            return spec
        if isinstance(spec, str):
            return cls.parse(spec)
        if isinstance(spec, dict):
            return cls.from_dict(spec)
        raise ValueError(f"cannot make an Impairment from {type(spec).__name__}")

    # ------------------------------------------------------------------ views
    @property
    def is_null(self) -> bool:
        """True when packets pass untouched (outages, loss, delay... all off)."""
        return (self.delay_ms == 0.0 and self.jitter_ms == 0.0 and self.loss == 0.0
                and self.gilbert_elliott is None and self.duplicate == 0.0 and self.reorder == 0.0
                and self.rate_kbps == 0.0 and not self.outages)

    def to_text(self) -> str:
        """The canonical string form; ``Impairment.parse(x.to_text())`` gives ``x`` back (to float rounding)."""
        g = self.gilbert_elliott
        correlation = f" {_fmt_pct(self.loss_correlation)}" if self.loss_correlation else ""
        loss = (f"loss gemodel {_fmt_pct(g.p)} {_fmt_pct(g.r)} {_fmt_pct(g.loss_bad)} {_fmt_pct(g.loss_good)}" if g
                else f"loss {_fmt_pct(self.loss)}{correlation}")
        reorder = f"reorder {_fmt_pct(self.reorder)} {_fmt_ms(self.reorder_ms)}"
        parts = ((self.delay_ms, f"delay {_fmt_ms(self.delay_ms)}"),
                 (self.jitter_ms, f"jitter {_fmt_ms(self.jitter_ms)}"),
                 (self.distribution != "uniform", f"distribution {self.distribution}"),
                 (g is not None or self.loss or self.loss_correlation, loss),
                 (self.duplicate, f"duplicate {_fmt_pct(self.duplicate)}"),
                 (self.reorder or self.reorder_ms != 10.0, reorder),
                 (self.rate_kbps, f"rate {self.rate_kbps * 1000.0!r}bit"),
                 (self.limit != 1000, f"limit {self.limit}"),
                 *((True, f"outage {start!r}s {duration!r}s") for start, duration in self.outages),
                 (self.rto_ms != 200.0, f"rto {_fmt_ms(self.rto_ms)}"),
                 (self.after_s, f"after {self.after_s!r}s"),
                 (not self.fifo, "unordered"))
        return " ".join(text for wanted, text in parts if wanted) or "none"

    def __str__(self) -> str:
        return self.to_text()


# ---------------------------------------------------------------------------- token parsers
_TIME_UNITS = {"us": 1e-3, "usec": 1e-3, "µs": 1e-3, "ms": 1.0, "msec": 1.0,
               "s": 1e3, "sec": 1e3, "secs": 1e3, "min": 60e3}
# tc's rate units (iproute2 tc_util.c), in bit/s; matched case-insensitively, "bps" = bytes/s
_RATE_UNITS = {"": 1.0, "bit": 1.0, "kbit": 1e3, "mbit": 1e6, "gbit": 1e9, "tbit": 1e12,
               "kibit": 1024.0, "mibit": 1024.0**2, "gibit": 1024.0**3, "tibit": 1024.0**4,
               "bps": 8.0, "kbps": 8e3, "mbps": 8e6, "gbps": 8e9, "tbps": 8e12,
               "kibps": 8 * 1024.0, "mibps": 8 * 1024.0**2, "gibps": 8 * 1024.0**3, "tibps": 8 * 1024.0**4}
_NUM = r"([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)"


def _is_time(tok: str) -> bool:
    m = re.fullmatch(_NUM + r"([a-zµ]+)", tok.lower())
    return bool(m and m.group(2) in _TIME_UNITS)


def _is_percent(tok: str) -> bool:
    return re.fullmatch(_NUM + "%", tok) is not None


def _time_ms(tok: str) -> float:
    m = re.fullmatch(_NUM + r"([a-zµ]*)", tok.lower())
    if not m:
        raise ValueError(f"bad time {tok!r}: expected a number with a unit, e.g. 50ms")
    if not m.group(2):
        raise ValueError(f"bad time {tok!r}: a unit is required (us, ms, s or min)")
    if m.group(2) not in _TIME_UNITS:
        raise ValueError(f"bad time unit in {tok!r}: use us, ms, s or min")
    return float(m.group(1)) * _TIME_UNITS[m.group(2)]


def parse_time_s(tok: str) -> float:
    """A time with a unit (``us``, ``ms``, ``s``, ``min``), e.g. ``"1.5s"`` or ``"250ms"``, in seconds."""
    return _time_ms(tok) / 1000.0


def _percent(tok: str) -> float:
    m = re.fullmatch(_NUM + "%", tok)
    if not m:
        raise ValueError(f"bad percentage {tok!r}: expected e.g. 2% or 0.5%")
    value = float(m.group(1)) / 100.0
    if value > 1.0:
        raise ValueError(f"bad percentage {tok!r}: above 100%")
    return value


def _rate_kbps(tok: str) -> float:
    m = re.fullmatch(_NUM + r"([a-z]*)", tok.lower())
    if not m or m.group(2) not in _RATE_UNITS:
        raise ValueError(f"bad rate {tok!r}: expected e.g. 2mbit, 500kbit or 100kbps (bytes/s as in tc)")
    return float(m.group(1)) * _RATE_UNITS[m.group(2)] / 1000.0


#: keywords followed by one value: keyword -> (field, what the value is, its reader)
_SINGLE = {"jitter": ("jitter_ms", "a time", _time_ms), "duplicate": ("duplicate", "a percentage", _percent),
           "rate": ("rate_kbps", "a rate", _rate_kbps), "rto": ("rto_ms", "a time", _time_ms),
           "after": ("after_s", "a time", parse_time_s)}


def _fmt_ms(ms: float) -> str:
    return f"{ms!r}ms"


def _fmt_pct(x: float) -> str:
    return f"{x * 100.0!r}%"


# ---------------------------------------------------------------------------- counters
@dataclass
class Counters:
    """What one :class:`Impairer` did. ``out`` counts released copies (duplicates included)."""

    packets_in: int = 0
    bytes_in: int = 0
    packets_out: int = 0
    bytes_out: int = 0
    dropped: dict[str, int] = field(default_factory=lambda: dict.fromkeys(DROP_REASONS, 0))
    duplicated: int = 0
    reordered: int = 0
    stalled: int = 0
    retransmitted: int = 0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def passed(self, copies: int, size_bytes: int) -> None:
        """Count ``copies`` released copies of a packet of ``size_bytes``."""
        self.packets_out += copies
        self.bytes_out += copies * size_bytes


# ---------------------------------------------------------------------------- the decisions
@dataclass(frozen=True, slots=True)
class _Params:
    """One immutable snapshot of what an :class:`Impairer` applies, in the caller's clock.

    Swapped whole by :meth:`Impairer.update`, :meth:`Impairer.cut` and :meth:`Impairer.restore`,
    read once per decision: a decision never sees half of a change.
    """

    impairment: Impairment
    delay: float
    jitter: float
    hold: float
    rto: float
    onset: float
    byte_time: float
    outages: tuple[tuple[float, float], ...]   # the impairment's windows, absolute
    cuts: tuple[tuple[float, float], ...]      # live cuts, absolute; end may be inf
    down: tuple[tuple[float, float], ...]      # outages and cuts, sorted (what datagrams see)

    @classmethod
    def of(cls, imp: Impairment, origin_s: float, cuts: tuple[tuple[float, float], ...]) -> _Params:
        outages = tuple((origin_s + s, origin_s + s + d) for s, d in imp.outages)
        return cls(imp, imp.delay_ms / 1000.0, imp.jitter_ms / 1000.0, imp.reorder_ms / 1000.0,
                   imp.rto_ms / 1000.0, origin_s + imp.after_s,
                   8.0 / (imp.rate_kbps * 1000.0) if imp.rate_kbps > 0 else 0.0,
                   outages, cuts, tuple(sorted(outages + cuts)))


def _window_end(windows: tuple[tuple[float, float], ...], t: float) -> float | None:
    """End of the window containing ``t`` in sorted ``windows`` (chained windows merged), or None."""
    end = None
    for a, b in windows:
        if a <= t < b or (end is not None and a <= end < b):
            end = b
            t = b
    return end


def _stall(outages: tuple[tuple[float, float], ...], t: float, stalled: bool) -> tuple[float, bool]:
    """``t`` moved to the end of the outage window containing it (and ``True``), else ``t`` and ``stalled``."""
    end = _window_end(outages, t) if outages else None
    return (t, stalled) if end is None else (end, True)


class Impairer:
    """Seeded decisions for one direction of one link.

    :meth:`decide` / :meth:`decide_stream` from one caller at a time; :meth:`update`, :meth:`cut`,
    :meth:`restore` and :meth:`outage_end` from any thread (one swap of an immutable snapshot). Variates
    are drawn in blocks of :attr:`BLOCK`, so a seed gives the same decisions for the same calls; outages
    count from ``origin_s``; ``mss`` sizes the lost segments of :meth:`decide_stream`.
    """

    BLOCK = 4096

    def __init__(self, impairment: Impairment | str | dict[str, Any] | None = None,
                 rng: np.random.Generator | int | None = None, origin_s: float = 0.0, mss: int = DEFAULT_MSS) -> None:
        imp = Impairment.coerce(impairment)
        if not math.isfinite(origin_s):
            raise ValueError(f"origin_s must be finite, got {origin_s}")
        if not isinstance(mss, int) or mss <= 0:
            raise ValueError(f"mss must be a positive int, got {mss!r}")
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.origin_s = float(origin_s)
        self.mss = mss
        self.counters = Counters()
        self.changes = 0                  # update / cut / restore calls applied
        self._change_lock = threading.Lock()
        self._p = _Params.of(imp, self.origin_s, ())
        self._busy_until = -math.inf      # rate: when the link finishes the previous packet
        self._last_release = -math.inf    # FIFO floor
        self._held: list[float] = []      # release times of packets held (for `limit`)
        self._bad = False                 # loss chain state (GE: Bad; Markov: previous lost)
        self._u = np.empty(0)
        self._ui = 0
        self._n = np.empty(0)
        self._ni = 0

    @property
    def impairment(self) -> Impairment:
        """What is applied now."""
        return self._p.impairment

    # ---------------------------------------------------------------- live changes
    def update(self, impairment: Impairment | str | dict[str, Any] | None) -> Impairment:
        """Apply ``impairment`` from the next decision on; returns it (validated).

        Keeps the random stream, counters, origin, FIFO floor, rate queue, loss-chain state and
        the live cuts (docs/experiments.md, "Live changes"). Bad input raises
        :class:`ValueError` and changes nothing.
        """
        imp = Impairment.coerce(impairment)
        with self._change_lock:
            self._p = _Params.of(imp, self.origin_s, self._p.cuts)
            self.changes += 1
        return imp

    def cut(self, now_s: float, duration_s: float | None = None) -> None:
        """Cut the link from ``now_s`` for ``duration_s`` seconds (None: until :meth:`restore`)."""
        self._check(now_s, 0)
        if duration_s is not None and not (isinstance(duration_s, (int, float))
                                           and math.isfinite(duration_s) and duration_s > 0.0):
            raise ValueError(f"cut duration must be a finite number of seconds > 0 or None, got {duration_s!r}")
        end = math.inf if duration_s is None else float(now_s) + float(duration_s)
        with self._change_lock:
            p = self._p
            cuts = tuple(sorted(p.cuts + ((float(now_s), end),)))
            self._p = _Params.of(p.impairment, self.origin_s, cuts)
            self.changes += 1

    def restore(self) -> None:
        """End every cut (current or pending). The impairment's own outage windows stay."""
        with self._change_lock:
            p = self._p
            self._p = _Params.of(p.impairment, self.origin_s, ())
            self.changes += 1

    def cut_end(self, t: float) -> float | None:
        """End of the live cut containing clock time ``t`` (``inf``: until restored), or None."""
        return _window_end(self._p.cuts, t)

    def outage_end(self, t: float) -> float | None:
        """When the link comes back if it is down at clock time ``t``: the end of the outage or cut
        window containing ``t`` (chained windows merged; ``inf`` for an open-ended cut), or None."""
        return _window_end(self._p.down, t)

    # ---------------------------------------------------------------- random streams
    def _uniform(self) -> float:
        if self._ui >= self._u.size:
            self._u = self.rng.random(self.BLOCK)
            self._ui = 0
        self._ui += 1
        return float(self._u[self._ui - 1])

    def _normal(self) -> float:
        if self._ni >= self._n.size:
            self._n = self.rng.standard_normal(self.BLOCK)
            self._ni = 0
        self._ni += 1
        return float(self._n[self._ni - 1])

    # ---------------------------------------------------------------- pieces
    def _lost(self, imp: Impairment) -> bool:
        """One packet through the loss model (Bernoulli, Markov-correlated or Gilbert–Elliott)."""
        ge = imp.gilbert_elliott
        if ge is not None:
            if self._bad:
                lost = self._uniform() < ge.loss_bad
                if self._uniform() < ge.r:
                    self._bad = False
            else:
                lost = self._uniform() < ge.loss_good
                if self._uniform() < ge.p:
                    self._bad = True
            return lost
        p = imp.loss
        if p <= 0.0:
            return False
        rho = imp.loss_correlation
        if rho > 0.0:
            q = rho + (1.0 - rho) * p if self._bad else (1.0 - rho) * p
            self._bad = self._uniform() < q
            return self._bad
        return self._uniform() < p

    def _latency(self, p: _Params) -> float:
        """Delay plus one jitter sample, seconds, never negative."""
        if p.jitter <= 0.0:
            return p.delay
        if p.impairment.distribution == "normal":
            j = self._normal() * p.jitter
        else:
            j = (2.0 * self._uniform() - 1.0) * p.jitter
        return max(0.0, p.delay + j)

    def _serialise(self, p: _Params, t: float, size: int) -> float:
        """When a packet entering the link at ``t`` has been sent at ``rate_kbps``."""
        if p.byte_time <= 0.0:
            return t
        start = t if t > self._busy_until else self._busy_until
        self._busy_until = start + size * p.byte_time
        return self._busy_until

    def _arrive(self, now_s: float, size_bytes: int) -> tuple[_Params, Counters]:
        """Check and count one arrival; the snapshot that decides it and the counters."""
        self._check(now_s, size_bytes)
        c = self.counters
        c.packets_in += 1
        c.bytes_in += size_bytes
        return self._p, c

    def _check(self, now_s: float, size_bytes: int) -> None:
        if not (isinstance(now_s, (int, float)) and math.isfinite(now_s)):
            raise ValueError(f"now_s must be a finite number, got {now_s!r}")
        if not isinstance(size_bytes, (int, np.integer)) or size_bytes < 0:
            raise ValueError(f"size_bytes must be an int >= 0, got {size_bytes!r}")

    # ---------------------------------------------------------------- datagrams
    def decide(self, now_s: float, size_bytes: int) -> list[float]:
        """Release times (caller's clock, seconds) of the copies of one datagram arriving now.

        Empty list: dropped (counted under ``loss``, ``outage`` — outage windows and cuts — or
        ``queue``). Two entries: the packet was duplicated. Times are never before ``now_s``.
        """
        p, c = self._arrive(now_s, size_bytes)
        if p.down and _window_end(p.down, now_s) is not None:
            c.dropped["outage"] += 1
            return []
        if now_s < p.onset:
            c.passed(1, size_bytes)
            return [float(now_s)]
        imp = p.impairment
        if self._lost(imp):
            c.dropped["loss"] += 1
            return []
        held = self._held
        if imp.limit:
            while held and held[0] <= now_s:
                heapq.heappop(held)
            if len(held) >= imp.limit:
                c.dropped["queue"] += 1
                return []
        copies = 2 if imp.duplicate > 0.0 and self._uniform() < imp.duplicate else 1
        out: list[float] = []
        for k in range(copies):
            t = self._serialise(p, now_s, size_bytes) + self._latency(p)
            if k == 0 and imp.reorder > 0.0 and self._uniform() < imp.reorder:
                # held back: later packets overtake it; it does not raise the FIFO floor
                t = max(t, self._last_release) + p.hold
                c.reordered += 1
            elif imp.fifo:
                if t < self._last_release:
                    t = self._last_release
                self._last_release = t
            out.append(t)
            if imp.limit and t > now_s:
                heapq.heappush(held, t)
        if copies == 2:
            c.duplicated += 1
            out.sort()
        c.passed(copies, size_bytes)
        return out

    # ---------------------------------------------------------------- byte streams
    def decide_stream(self, now_s: float, size_bytes: int) -> float:
        """Release time of one in-order chunk of a byte stream (TCP) arriving now.

        Never drops: an outage window stalls the chunk until the window ends; a lost segment
        (Bernoulli / correlated / Gilbert–Elliott per ``mss`` bytes) delays the chunk by
        ``rto_ms``; then rate, delay and jitter; release times never decrease. Live cuts are
        not applied here: the sender holds bytes while :meth:`outage_end` is not None.
        """
        p, c = self._arrive(now_s, size_bytes)
        t, stalled = _stall(p.outages, float(now_s), False)
        if t < p.onset:
            return self._release_stream(t, stalled, size_bytes)
        imp = p.impairment
        if imp.loss > 0.0 or imp.gilbert_elliott is not None:
            segments = max(1, -(-size_bytes // self.mss))
            lost = False
            if imp.gilbert_elliott is None and imp.loss_correlation == 0.0:
                lost = self._uniform() < 1.0 - (1.0 - imp.loss) ** segments
            else:
                for _ in range(segments):
                    lost = self._lost(imp) or lost
            if lost:
                t += p.rto
                c.retransmitted += 1
        t, stalled = _stall(p.outages, self._serialise(p, t, size_bytes) + self._latency(p), stalled)
        return self._release_stream(t, stalled, size_bytes)

    def _release_stream(self, t: float, stalled: bool, size_bytes: int) -> float:
        """Release a stream chunk at ``t`` or at the FIFO floor, whichever is later, and count it."""
        t = max(t, self._last_release)
        self._last_release = t
        self.counters.stalled += stalled
        self.counters.passed(1, size_bytes)
        return t

    def stats(self) -> dict[str, Any]:
        """Counters as a plain dict (JSON-ready)."""
        return self.counters.as_dict()


# ---------------------------------------------------------------------------- --impair
#: the link classes an ``--impair`` value may name
IMPAIR_CLASSES = ("udp", "tcp")


@dataclass(frozen=True)
class ImpairArg:
    """One ``--impair`` value, ``[LINK[/udp|/tcp]=]SPEC``: which links (None: not named) and class (None: both)."""

    link: str | None
    cls: str | None
    spec: str
    impairment: Impairment


def parse_impair_arg(text: str, *, named: bool | None = None) -> ImpairArg:
    """Read an ``--impair`` value, the one grammar of every command that takes one: ``[LINK[/udp|/tcp]=]SPEC``
    with SPEC as :meth:`Impairment.parse` reads it (``skynet up``/``mission``: LINK defaults to every link;
    ``skynet netem``: one proxy is one link, so no LINK). ``named``: True requires LINK=, False refuses it.

    Raises ValueError with a one-line message naming the value.

    >>> parse_impair_arg("uav2/udp=delay 50ms loss 2%").cls
    'udp'
    >>> parse_impair_arg("delay 50ms").link is None
    True
    >>> parse_impair_arg("uav2=", named=True)
    Traceback (most recent call last):
    ...
    ValueError: --impair 'uav2=': no SPEC after '=' (e.g. uav2="delay 50ms loss 2%")
    """
    if not isinstance(text, str):
        raise ValueError(f"--impair: expected text, got {type(text).__name__}")
    head, sep, spec = text.partition("=")
    link = cls = None
    if sep:
        link, slash, cls_text = head.strip().partition("/")
        if not link:
            raise ValueError(f"--impair {text!r}: no LINK before '=' (LINK[/udp|/tcp]=SPEC)")
        if slash:
            if cls_text not in IMPAIR_CLASSES:
                raise ValueError(f"--impair {text!r}: class {cls_text!r} is not udp or tcp")
            cls = cls_text
        if not spec.strip():
            raise ValueError(f"--impair {text!r}: no SPEC after '=' (e.g. {link}=\"delay 50ms loss 2%\")")
    else:
        spec = head
    if named and link is None:
        raise ValueError(f"--impair {text!r}: name the link, LINK[/udp|/tcp]=SPEC (e.g. all=\"{text.strip()}\")")
    if named is False and link is not None:
        raise ValueError(f"--impair {text!r}: this proxy is one link; give SPEC alone (e.g. \"{spec.strip()}\")")
    try:
        impairment = Impairment.parse(spec)
    except ValueError as e:
        raise ValueError(f"--impair {text!r}: {e}") from None
    return ImpairArg(link, cls, spec.strip(), impairment)
