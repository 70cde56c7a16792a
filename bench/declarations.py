"""What a valid identity's declarations cost the gateway: uav2's certificate declaring N entities (rounds below) on
a real ``skynet gateway`` (mutual TLS, the ACL, the accept guard); the gateway's resident memory before, with them
held, after they are undeclared and after uav2 disconnects.

Rounds: ``state_subs``, subscribers on new keys its grant on ``uav/*/state`` admits (``uav/x1/state``, ...);
``adv``, queryables under its own ``camera/@adv/**`` (zenoh.ext's recovery keys); ``same_key``, N queryables on
one exact key (its ``cmd``); ``denied``, queryables under another UAV's camera (the ACL refuses them).

Zenoh 1.10 has no per-session or per-identity cap on declarations: its configuration bounds sessions
(``transport/unicast/max_sessions``), links per session (``max_links``), pending accepts (``accept_pending``),
message sizes (``transport/link/rx/max_message_size``, the ``low_pass_filter`` interceptor) and put rates
(``downsampling``), and its ACL decides *which* key expressions a subject may declare, not *how many*. The
figures say what remains (docs/security.md).

    .venv/bin/python bench/declarations.py [--n 3000] [--out bench/results/declarations.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol import keys  # noqa: E402
from protocol.bus import Bus, BusConfig  # noqa: E402
from protocol.heap import settled_resident_mb  # noqa: E402
from protocol.keyset import KeySet  # noqa: E402
from services.orchestration.process import ProcessGroup, free_port  # noqa: E402
from services.orchestration.trustmode import dev_keys, tls_endpoints  # noqa: E402

FLEET = "bench"


ROUNDS = ("state_subs", "adv", "same_key", "denied")


def declare(bus: Bus, label: str, i: int) -> object:
    root = keys.fleet_root(FLEET)
    if label == "state_subs":
        return bus.session.declare_subscriber(f"{root}/uav/x{i}/state", lambda s: None)
    if label == "adv":
        return bus.session.declare_queryable(f"{keys.camera(FLEET, 2)}/@adv/pub/b{i}/1/_", lambda q: None)
    if label == "same_key":
        return bus.session.declare_queryable(keys.cmd(FLEET, 2), lambda q: None)
    return bus.session.declare_queryable(f"{keys.camera(FLEET, 1)}/@adv/pub/d{i}/1/_", lambda q: None)


def connect(cfg: BusConfig, within_s: float = 30.0) -> Bus:
    """uav2's session, retried for a while (a loaded machine)."""
    end = time.monotonic() + within_s
    while True:
        try:
            return Bus(cfg, FLEET, "uav2")
        except zenoh.ZError:
            if time.monotonic() > end:
                raise
            time.sleep(2.0)


def variant(ks: Path, a: argparse.Namespace, env: dict) -> dict:
    """One gateway and every round on it."""
    ends = tls_endpoints("127.0.0.1", free_port(), free_port())
    group = ProcessGroup(echo=None, env=env)
    out: dict = {}
    try:
        gw = group.start("gw", ["gateway", "--fleet", FLEET, "--multilink", "--keys", str(ks), "--period-s", "0.5",
                                *[x for e in ends for x in ("--listen", e)]])
        assert gw.wait_for("router up", 30), "\n".join(gw.lines)
        pid = gw.proc.pid
        k = KeySet(ks, "uav2")
        cfg = BusConfig(mode="client", connect=ends, multilink=True, tls_ca=str(k.ca), tls_cert=str(k.tls_cert),
                        tls_key=str(k.tls_key))
        out["rss_start_mb"] = settled_resident_mb(pid, 8.0)
        for label in a.rounds.split(","):
            rss0 = settled_resident_mb(pid, 8.0)
            with connect(cfg) as bus:
                t0 = time.perf_counter()
                held = [declare(bus, label, i) for i in range(a.n)]
                out[f"{label}_declare_s"] = round(time.perf_counter() - t0, 2)
                out[f"{label}_held_mb"] = round(settled_resident_mb(pid, 8.0) - rss0, 1)
                for q in held:
                    q.undeclare()  # type: ignore[attr-defined]
                out[f"{label}_undeclared_mb"] = round(settled_resident_mb(pid, 8.0) - rss0, 1)
            time.sleep(2.0)
            out[f"{label}_after_disconnect_mb"] = round(settled_resident_mb(pid, 8.0) - rss0, 1)
            print(label, {k_: v for k_, v in out.items() if k_.startswith(label)}, flush=True)
        out["rss_end_mb"] = settled_resident_mb(pid, 8.0)
    finally:
        group.stop()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=3000,
                    help="declarations per round (the declaring takes longer than linearly)")
    ap.add_argument("--rounds", default=",".join(ROUNDS))
    ap.add_argument("--out", default=None)
    ap.add_argument("--gateway-env", action="append", default=[], metavar="NAME=VALUE",
                    help="an environment variable for the gateway process (e.g. MALLOC_ARENA_MAX=1)")
    a = ap.parse_args()
    ks = dev_keys(Path(tempfile.mkdtemp(prefix="skynet-decl-")) / "keys", 3)
    env = dict(x.split("=", 1) for x in a.gateway_env)
    result: dict = {"n": a.n, "gateway_env": env, **variant(ks, a, env)}
    print(json.dumps(result, indent=1))
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
