"""Fuzzing every decoder and input entry point: only typed errors, no crash, hang or growth.

Each target takes bytes (text targets decode them as UTF-8 with replacement, as a command line or a
file would arrive) and may raise only the error types it documents; anything else is a *crash*, an
input taking longer than ``--hang`` seconds a *hang* (SIGALRM). Inputs are mutations of valid seeds
(bit flips, byte changes, truncation, duplication, splices; AFL's havoc stage, in short) and plain
random bytes, from a seeded generator, so a run repeats. Per target it prints inputs, inputs/s,
rejected (typed error), accepted, crashes, hangs, the slowest input and the peak RSS growth, and
writes JSON to ``bench/results/fuzz.json``.

    .venv/bin/python bench/fuzz.py [--n 100000] [--target codec ...] [--seed 0]

The suite runs the same targets with hypothesis (``tests/bench/test_fuzz.py``, a few hundred
inputs each).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import signal
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol import codec, keys  # noqa: E402
from protocol import messages as m  # noqa: E402
from protocol.budget import Budget, Limit  # noqa: E402
from protocol.imagery import pack_image, split_payload  # noqa: E402
from protocol.jitter import JitterBuffers  # noqa: E402
from protocol.rtp import RtpError, RtpSender, ssrc_for, unpack_frame  # noqa: E402


@dataclass
class Target:
    name: str
    run: Callable[[bytes], object]
    allowed: tuple[type[BaseException], ...]
    seeds: list[bytes]


def _text(data: bytes) -> str:
    return data.decode("utf-8", errors="replace")


def _meta(uav: int = 1) -> m.ImageMeta:
    return m.ImageMeta(uav=uav, capture_id=3, t=2.0, stamp=1.7e9, cam_pos=(1, 2, 3), cam_rot=(1, 0, 0, 0, 1, 0, 0, 0, 1),
                       intrinsics=m.Intrinsics(width=64, height=48, fx=50, fy=50, cx=32, cy=24))


def _messages() -> list[m.Message]:
    traj = m.Trajectory(uav=1, waypoints=[m.Waypoint(t=0, pos=(0, 0, 10)), m.Waypoint(t=2, pos=(1, 0, 10), capture_id=1)])
    box = m.Box(lo=(0, 0, 0), hi=(141, 101, 40))
    return [
        m.VehicleState(uav=2, seq=7, t=1.5, stamp=1.7e9, pos=(1.0, 2.0, 30.0), vel=(0.1, 0.0, -0.2), att=(0, 0, 1.2),
                       rates=(0, 0.1, 0), mode=m.Mode.MISSION, armed=True),
        m.UploadTrajectory(uav=1, cmd_id=1, trajectory=traj, geofence=box), m.Takeoff(uav=1, cmd_id=2, altitude=10),
        m.Start(uav=1, cmd_id=3, t0_stamp=1.7e9), m.Resume(uav=1, cmd_id=6), m.Heartbeat(seq=3, stamp=1.7e9),
        m.SetFormation(uav=1, cmd_id=8, offsets={1: (0, 0, 2), 2: (3, 0, -1)}),
        m.DefectReport(uav=1, capture_id=4, stamp_capture=1.7e9, stamp_report=1.7e9, method="it+",
                       frame=m.FrameEvidence(ssrc=ssrc_for(1), seq=9, digest="ab" * 32)),
        m.Event(source="uav/1", stamp=1.7e9, kind="failsafe", level=m.Level.WARNING, data={"x": 1.0}),
        m.PlanRequest(scenario={"name": "x", "origin": {"lat": 1, "lon": 2}, "box": {"lo": [0, 0, 0], "hi": [10, 10, 40]},
                      "start": [1, 1, 10], "goal": [9, 9, 10]}, seed=3, particles=20),
    ]


def _command(data: bytes) -> object:
    """The board's command entry point: decode as a command, then validate (edge.geometry.validate)."""
    from edge.geometry.validate import validate_command

    cmd = codec.decode(data, m.COMMAND_TYPES)
    return validate_command(cmd, 1, m.Box(lo=(0, 0, 0), hi=(141, 101, 40)), 12.0)


_JB = JitterBuffers(capacity=64, playout_delay_s=0.05, release_late=True)
_CLOCK = [0.0]


def _jitter(data: bytes) -> object:
    """The detector's frame entry point: RTP parse, SSRC check, jitter buffer (bounded state across inputs)."""
    from services.detector.service import frame_source

    header, payload = unpack_frame(data)
    _CLOCK[0] += 0.001
    if frame_source("skynet/demo/uav/1/camera", header.ssrc) is None:
        return None
    return _JB.push(header, payload, _CLOCK[0])


_SCENARIO_FILE = Path(tempfile.gettempdir()) / f"skynet-fuzz-{os.getpid()}.toml"


def _scenario(data: bytes) -> object:
    from services.planner.scenario import load_scenario

    _SCENARIO_FILE.write_bytes(data)
    return load_scenario(_SCENARIO_FILE)


def _fault(data: bytes) -> object:
    from services.orchestration.faults import parse_fault

    return parse_fault(_text(data))


def _impair(data: bytes) -> object:
    from services.netem.model import Impairment

    return Impairment.parse(_text(data))


def _schedule(data: bytes) -> object:
    from services.netem.schedule import parse_schedule

    return parse_schedule(_text(data))


def _key(data: bytes) -> object:
    return keys.parse(_text(data))


_BUDGET = Budget(Limit(20.0, 20, 4096), max_sources=64)


def _budget(data: bytes) -> object:
    """protocol.budget under arbitrary sources and sizes (its state must stay bounded)."""
    _CLOCK[0] += 0.001
    return _BUDGET.admit(_text(data[:40]), len(data) * 64, _CLOCK[0])


def targets() -> list[Target]:
    from services.netem.schedule import ScheduleError
    from services.orchestration.faults import MAX_FAULT_S  # noqa: F401  (import errors surface here, not per input)
    from services.planner.scenario import ScenarioError, default_scenario_path

    msgs = [codec.encode(x) for x in _messages()]
    sender = RtpSender(ssrc_for(1), initial_seq=100)
    frames = [pack_image(sender, _meta(), b"\xff\xd8jpeg bytes\xff\xd9", 1.0) for _ in range(3)]
    frames.append(RtpSender(0x12345678).frame(b"x" * 20, 1.0))
    payloads = [f[12:] for f in frames]
    return [
        Target("codec.decode", lambda d: codec.decode(d), (codec.CodecError,), msgs),
        Target("command (decode + validate)", _command, (codec.CodecError,), msgs[1:7]),
        Target("rtp.unpack_frame", unpack_frame, (RtpError,), frames),
        Target("imagery.split_payload", split_payload, (codec.CodecError,), payloads),
        Target("detector frame path", _jitter, (RtpError,), frames),
        Target("scenario file", _scenario, (ScenarioError,), [default_scenario_path().read_bytes()]),
        Target("fault spec", _fault, (ValueError,), [b"20s kill gateway for 3s", b"15s cut uplinks for 8s",
                                                     b"15s partition uav1-uav2 for 10s", b"1.5min kill uav3"]),
        Target("netem spec", _impair, (ValueError,), [b"delay 200ms 20ms distribution normal loss 20%",
                                                      b"loss gemodel 1% 30% outage 10s 5s after 2s rate 2mbit",
                                                      b"duplicate 1% reorder 5%"]),
        Target("netem schedule", _schedule, (ScheduleError, ValueError),
               [b'at 25s cut 5s\nat 40s "delay 200ms loss 20%"\nat 60s clear\n']),
        Target("keys.parse", _key, (keys.KeyError_,), [b"skynet/demo/uav/3/state", b"skynet/demo/rcu/planner/plan",
                                                       b"skynet/demo/gateway/1/stats"]),
        Target("budget.admit", _budget, (), [b"skynet/demo/uav/1/event", b"x" * 200]),
    ]


def mutate(rng: random.Random, seeds: list[bytes]) -> bytes:
    """One input: 1 in 8 plain random bytes, else a seed through 1..8 havoc mutations."""
    if rng.random() < 0.125 or not seeds:
        return rng.randbytes(rng.randrange(0, 256))
    b = bytearray(rng.choice(seeds))
    for _ in range(rng.randrange(1, 9)):
        op = rng.randrange(7)
        if op == 0 and b:  # flip a bit
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
        elif op == 1 and b:  # an interesting byte
            b[rng.randrange(len(b))] = rng.choice((0x00, 0x01, 0x7F, 0x80, 0xFF, 0xC0, 0xDF, 0xE0))
        elif op == 2 and b:  # truncate
            del b[rng.randrange(len(b)):]
        elif op == 3 and b:  # delete a run
            i = rng.randrange(len(b))
            del b[i:i + rng.randrange(1, 16)]
        elif op == 4 and b:  # duplicate a run
            i = rng.randrange(len(b))
            b[i:i] = b[i:i + rng.randrange(1, 32)]
        elif op == 5:  # insert random bytes
            i = rng.randrange(len(b) + 1)
            b[i:i] = rng.randbytes(rng.randrange(1, 16))
        elif op == 6 and len(seeds) > 1:  # splice with another seed
            other = rng.choice(seeds)
            b = b[: rng.randrange(len(b) + 1)] + other[rng.randrange(len(other) + 1):]
    return bytes(b[:65536])


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def fuzz(target: Target, n: int, seed: int, hang_s: float) -> dict:
    rng = random.Random(f"{seed}:{target.name}")
    crashes: list[dict] = []
    hangs: list[str] = []
    rejected = accepted = 0
    slowest = (0.0, b"")
    for s in target.seeds:  # warm up: first-call imports are not the input's cost
        try:
            target.run(s)
        except Exception:
            pass
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    old = signal.signal(signal.SIGALRM, _alarm)
    t0 = time.perf_counter()
    try:
        for _ in range(n):
            data = mutate(rng, target.seeds)
            t = time.perf_counter()
            try:
                signal.setitimer(signal.ITIMER_REAL, hang_s)
                try:
                    target.run(data)
                    accepted += 1
                except Hang:
                    raise
                except target.allowed:
                    rejected += 1
                except Exception as exc:  # a crash: an error the target does not document
                    crashes.append({"error": f"{type(exc).__name__}: {exc}"[:300], "input": data[:200].hex()}
                                   if len(crashes) < 5 else {})
                finally:
                    signal.setitimer(signal.ITIMER_REAL, 0)
            except Hang:  # also when the alarm fires as the input ends
                hangs.append(data.hex())
            dt = time.perf_counter() - t
            if dt > slowest[0]:
                slowest = (dt, data)
    finally:
        signal.signal(signal.SIGALRM, old)
    wall = time.perf_counter() - t0
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"target": target.name, "inputs": n, "inputs_per_s": n / wall, "rejected": rejected, "accepted": accepted,
            "crashes": len(crashes), "crash_examples": [c for c in crashes if c][:5], "hangs": len(hangs),
            "hang_examples": hangs[:3],
            "slowest_ms": 1000 * slowest[0], "peak_rss_growth_mb": (rss1 - rss0) / 1024, "wall_s": wall}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=100_000, help="inputs per target")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hang", type=float, default=1.0, help="an input slower than this is a hang, s")
    p.add_argument("--target", action="append", default=None, help="substring of target names (repeatable)")
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "fuzz.json"))
    args = p.parse_args(argv)
    chosen = [t for t in targets() if not args.target or any(s in t.name for s in args.target)]
    rows = []
    print(f"{'target':<28} {'inputs':>8} {'inputs/s':>9} {'rejected':>9} {'accepted':>9} {'crashes':>7} "
          f"{'hangs':>5} {'slowest':>9} {'RSS +MB':>8}")
    for t in chosen:
        r = fuzz(t, args.n, args.seed, args.hang)
        rows.append(r)
        print(f"{r['target']:<28} {r['inputs']:>8} {r['inputs_per_s']:>9.0f} {r['rejected']:>9} {r['accepted']:>9} "
              f"{r['crashes']:>7} {r['hangs']:>5} {r['slowest_ms']:>7.1f}ms {r['peak_rss_growth_mb']:>8.1f}", flush=True)
        for c in r["crash_examples"]:
            print(f"    crash: {c['error']}  input={c['input'][:80]}")
        for h in r["hang_examples"]:
            print(f"    hang: input={h[:160]}")
    _SCENARIO_FILE.unlink(missing_ok=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"seed": args.seed, "n": args.n, "targets": rows}, indent=1))
    print(f"wrote {out}")
    return 1 if any(r["crashes"] or r["hangs"] for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())
