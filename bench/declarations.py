"""What a valid identity's declarations cost the gateway: uav2's certificate declaring N queryables under its
own ``camera/@adv/**`` (what its access-control grant allows: zenoh.ext's advanced publisher answers recovery
queries there), the gateway's resident memory before, after, after uav2 disconnects and after a second round.

Zenoh 1.10 has no per-session or per-identity cap on declarations: its configuration bounds sessions
(``transport/unicast/max_sessions``), links per session (``max_links``), pending accepts (``accept_pending``),
message sizes (``transport/link/rx/max_message_size``, the ``low_pass_filter`` interceptor) and put rates
(``downsampling``), and its ACL decides *which* key expressions a subject may declare, not *how many*. The
figures say what remains (README, threat model, "Trust").

    .venv/bin/python bench/declarations.py [--n 4000] [--out bench/results/declarations.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol import keys  # noqa: E402
from protocol.bus import Bus, BusConfig  # noqa: E402
from protocol.keyset import KeySet  # noqa: E402
from services.orchestration.process import ProcessGroup, free_port  # noqa: E402
from services.orchestration.trustmode import dev_keys, tls_endpoints  # noqa: E402

FLEET = "bench"


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def settled_rss(pid: int, wait_s: float = 8.0) -> float:
    """The gateway's RSS once it stops moving (declarations are processed asynchronously)."""
    last, t_end = rss_mb(pid), time.monotonic() + wait_s
    while time.monotonic() < t_end:
        time.sleep(1.0)
        now = rss_mb(pid)
        if abs(now - last) < 0.2:
            return now
        last = now
    return last


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=4000,
                    help="declarations per round (the declaring takes longer than linearly)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--gateway-env", action="append", default=[], metavar="NAME=VALUE",
                    help="an environment variable for the gateway process (e.g. MALLOC_ARENA_MAX=1)")
    a = ap.parse_args()
    ks = dev_keys(Path(tempfile.mkdtemp(prefix="skynet-decl-")) / "keys", 3)
    ends = tls_endpoints("127.0.0.1", free_port(), free_port())
    env = dict(x.split("=", 1) for x in a.gateway_env)
    group = ProcessGroup(echo=None, env=env)
    out: dict = {"n": a.n, "gateway_env": env}
    try:
        gw = group.start("gw", ["gateway", "--fleet", FLEET, "--multilink", "--keys", str(ks),
                                *[x for e in ends for x in ("--listen", e)]])
        assert gw.wait_for("router up", 30), "\n".join(gw.lines)
        pid = gw.proc.pid
        k = KeySet(ks, "uav2")
        cfg = BusConfig(mode="client", connect=ends, multilink=True, tls_ca=str(k.ca), tls_cert=str(k.tls_cert),
                        tls_key=str(k.tls_key))
        own = keys.camera(FLEET, 2)
        other = keys.camera(FLEET, 1)
        out["rss_start_mb"] = settled_rss(pid)
        print("gateway up, rss", out["rss_start_mb"], flush=True)
        for label, base in (("own", own), ("own_again", own), ("denied", other)):
            with Bus(cfg, FLEET, "uav2") as bus:
                t0 = time.perf_counter()
                qs = [bus.session.declare_queryable(f"{base}/@adv/pub/{label}{i}/1/_", lambda q: None)
                      for i in range(a.n)]
                out[f"{label}_declare_s"] = round(time.perf_counter() - t0, 2)
                print(label, "declared in", out[f"{label}_declare_s"], "s", flush=True)
                out[f"rss_{label}_held_mb"] = settled_rss(pid)
                for q in qs:
                    q.undeclare()
                out[f"rss_{label}_undeclared_mb"] = settled_rss(pid)
            time.sleep(2.0)
            out[f"rss_after_{label}_disconnect_mb"] = settled_rss(pid)
        out["held_kb_per_declaration"] = round((out["rss_own_held_mb"] - out["rss_start_mb"]) * 1024 / a.n, 2)
        out["second_round_growth_mb"] = round(out["rss_own_again_held_mb"] - out["rss_own_held_mb"], 1)
        out["denied_growth_mb"] = round(out["rss_denied_held_mb"] - out["rss_after_own_again_disconnect_mb"], 1)
    finally:
        group.stop()
    for k_, v in out.items():
        print(f"{k_:32} {v}")
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
