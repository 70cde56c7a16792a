"""Two gateways (Zenoh routers) linked over one link or over two (the multilink pair): how often a liveliness
token declared at one site is never seen at the other (docs/multi-site.md).

Each round opens router B (listening, dialling A) with a client, then router A a moment later (0, 0.3 or 0.6 s:
the dialler is retrying, as in compose where the sites start in any order) with a client; each client declares
a token and watches for the other's; a round fails when either token is not seen within ``--wait-s``. The two
ways alternate round by round, so that both see the same machine.

    .venv/bin/python bench/router_links.py [--rounds 40] [--wait-s 6] [--out bench/results/router_links.json]

Prints a line per way and writes the figures as JSON (``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol.bus import BusConfig  # noqa: E402
from services.orchestration.process import free_port  # noqa: E402


def one_round(links: int, delay_s: float, wait_s: float) -> dict:
    """One pair of routers; whether each side saw the other's token, and how long that took."""
    a_ep = [f"tcp/127.0.0.1:{free_port()}?rel=1", f"tcp/127.0.0.1:{free_port()}?rel=0"]
    b_ep = [f"tcp/127.0.0.1:{free_port()}?rel=1"]
    sessions = []

    def open_(cfg: BusConfig) -> zenoh.Session:
        sessions.append(zenoh.open(cfg.to_zenoh()))
        return sessions[-1]

    try:
        open_(BusConfig(mode="router", listen=b_ep, connect=a_ep[:links], multilink=True, lease_s=2))
        cb = open_(BusConfig(mode="client", connect=b_ep))
        at_b: list[str] = []
        sub_b = cb.liveliness().declare_subscriber("x/**", lambda s: at_b.append(str(s.key_expr)), history=True)
        time.sleep(delay_s)
        open_(BusConfig(mode="router", listen=a_ep, multilink=True, lease_s=2))
        ca = open_(BusConfig(mode="client", connect=a_ep[:1]))
        at_a: list[str] = []
        sub_a = ca.liveliness().declare_subscriber("y/**", lambda s: at_a.append(str(s.key_expr)), history=True)
        tokens = [ca.liveliness().declare_token("x/a"), cb.liveliness().declare_token("y/b")]
        t0 = time.monotonic()
        while time.monotonic() - t0 < wait_s and not (at_a and at_b):
            time.sleep(0.02)
        seen_s = time.monotonic() - t0
        for t in tokens:
            t.undeclare()
        sub_a.undeclare()
        sub_b.undeclare()
        return {"a_to_b": bool(at_b), "b_to_a": bool(at_a), "seen_s": round(seen_s, 3)}
    finally:
        for s in reversed(sessions):
            s.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=40, help="rounds of each way")
    ap.add_argument("--wait-s", type=float, default=6.0)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "router_links.json")
    a = ap.parse_args()
    runs: dict[str, list[dict]] = {"one link": [], "two links": []}
    for r in range(a.rounds):
        for name, links in (("one link", 1), ("two links", 2)):
            runs[name].append(one_round(links, 0.3 * (r % 3), a.wait_s))
    result = {"rounds": a.rounds, "wait_s": a.wait_s}
    for name, rs in runs.items():
        lost = [r for r in rs if not (r["a_to_b"] and r["b_to_a"])]
        seen = sorted(r["seen_s"] for r in rs if r not in lost)
        result[name] = {"token never seen": len(lost), "of": len(rs),
                        "seen within p50 s": seen[len(seen) // 2] if seen else None}
        print(f"{name:9s}: a token never seen in {len(lost)} of {len(rs)} rounds"
              + (f" (the others within {seen[len(seen) // 2]:.2f} s p50)" if seen else ""))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=1))
    print(f"written {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
