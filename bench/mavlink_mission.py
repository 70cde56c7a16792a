"""The whole 3-UAV mission three ways, side by side in one run (sequentially, same seed and speed):

- ``sim``            the built-in vehicle (``--vehicle sim``);
- ``mavlink-guided`` each edge streams GUIDED position targets to its own sim autopilot;
- ``mavlink-auto``   each edge uploads its trajectory as a waypoint mission and flies it in AUTO,
                     kept in formation by DO_CHANGE_SPEED (``--flight auto``).

Figures from each run's report.json: formation RMS / max (m), captures imaged / planned, the GCS
command round trip (command -> acknowledgement over the bus, p50 / p95 ms: with a MAVLink vehicle
it includes the autopilot's COMMAND_ACK), wall time. Writes bench/results/mavlink_mission.json.

    .venv/bin/python bench/mavlink_mission.py [--speed 4] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNS = {"sim": ["--vehicle", "sim"], "mavlink-guided": ["--vehicle", "mavlink", "--flight", "guided"],
        "mavlink-auto": ["--vehicle", "mavlink", "--flight", "auto"]}


def run(name: str, extra: list[str], speed: float, seed: int, out: Path) -> dict:
    proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", *extra, "--speed", str(speed),
                           "--seed", str(seed), "--quiet", "--out", str(out)], cwd=ROOT, capture_output=True,
                          text=True, timeout=900)
    if proc.returncode != 0 or not (out / "report.json").exists():
        return {"run": name, "ok": False, "error": (proc.stdout + proc.stderr)[-1500:]}
    r = json.loads((out / "report.json").read_text())
    lat = r["links"]["command"]["latency_ms"]
    return {"run": name, "ok": bool(r["success"]), "formation_rms_m": r["formation"]["rms_m"],
            "formation_max_m": r["formation"]["max_m"], "captures_imaged": r["captures"]["imaged"],
            "captures_planned": r["captures"]["planned"], "command_p50_ms": lat["p50"], "command_p95_ms": lat["p95"],
            "commands": lat["n"], "wall_time_s": r["wall_time_s"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "bench/results/mavlink_mission.json"))
    a = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, extra in RUNS.items():
            rows.append(run(name, extra, a.speed, a.seed, Path(tmp) / name))
            print(json.dumps(rows[-1]), flush=True)
    print(f"\n{'run':16} {'ok':>3} {'RMS m':>6} {'max m':>6} {'captures':>9} {'cmd p50':>8} {'cmd p95':>8} {'wall s':>7}")
    for r in rows:
        if not r.get("formation_rms_m"):
            print(f"{r['run']:16} {'no':>3}  {r.get('error', '')[:200]}")
            continue
        print(f"{r['run']:16} {'yes' if r['ok'] else 'no':>3} {r['formation_rms_m']:6.2f} {r['formation_max_m']:6.2f} "
              f"{r['captures_imaged']:>4}/{r['captures_planned']:<4} {r['command_p50_ms']:7.1f}  {r['command_p95_ms']:7.1f} "
              f"{r['wall_time_s']:7.1f}")
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"speed": a.speed, "seed": a.seed, "runs": rows}, indent=2))
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
