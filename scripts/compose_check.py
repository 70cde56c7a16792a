"""Check a compose mission's report folder (scripts/compose-e2e.sh): verdict, captures, formation, impairment.

    python scripts/compose_check.py REPORT_DIR [--impaired uav2 --delay-ms 100] [--json OUT]

Exit 0 when every check holds, 1 otherwise (each failed check printed). The checks: the mission
succeeded; every planned capture was imaged; the formation RMS shape error is under 1 m (as with the
launcher, README "Experiments"); and, with ``--impaired``, the named UAV's telemetry age (rx − stamp,
median over its MISSION-phase states) exceeds every other UAV's by at least 80 % of ``--delay-ms``
(the impairment was applied on its link and only there); with ``--gateways N`` (compose/sites.yml), that
the report has the statistics of N gateways and that each one has a router link to another and UAV peers.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any

FORMATION_RMS_LIMIT_M = 1.0
DELAY_FRACTION = 0.8


def telemetry_age_ms(record: dict[str, Any]) -> dict[int, float]:
    """Per UAV, the median state age rx − stamp (ms) over its MISSION-phase states in ``record.json``."""
    ages: dict[int, list[float]] = {}
    for s in record.get("states", []):
        m = s["msg"]
        if m.get("mode") == "mission":
            ages.setdefault(int(m["uav"]), []).append((s["rx"] - m["stamp"]) * 1e3)
    return {u: statistics.median(a) for u, a in sorted(ages.items()) if a}


def check(report: dict[str, Any], record: dict[str, Any], impaired: str | None = None,
          delay_ms: float = 0.0, gateways: int | None = None) -> tuple[list[str], dict[str, Any]]:
    """(failures, figures) of one mission; no failure means the run is what the issue asks for."""
    fails: list[str] = []
    cap = report.get("captures") or {}
    form = report.get("formation") or {}
    ages = telemetry_age_ms(record)
    figures = {"success": report.get("success"), "captures": [cap.get("imaged"), cap.get("planned")],
               "formation_rms_m": form.get("rms_m"), "telemetry_age_ms": ages,
               "wall_time_s": (report.get("mission") or {}).get("wall_time_s")}
    if report.get("success") is not True:
        fails.append(f"mission failed: {report.get('failures')}")
    if not cap.get("planned") or cap.get("imaged") != cap.get("planned"):
        fails.append(f"captures imaged {cap.get('imaged')} of {cap.get('planned')}")
    rms = form.get("rms_m")
    if not isinstance(rms, (int, float)) or not rms < FORMATION_RMS_LIMIT_M:
        fails.append(f"formation RMS {rms} m, not under {FORMATION_RMS_LIMIT_M} m")
    if impaired is not None:
        uav = int(impaired.removeprefix("uav"))
        others = [a for u, a in ages.items() if u != uav]
        if uav not in ages or not others:
            fails.append(f"no MISSION-phase telemetry to compare for {impaired}: ages {ages}")
        elif ages[uav] - max(others) < DELAY_FRACTION * delay_ms:
            fails.append(f"impairment not applied: {impaired} telemetry age {ages[uav]:.1f} ms vs others "
                         f"{max(others):.1f} ms (expected at least {DELAY_FRACTION * delay_ms:.0f} ms more)")
    if gateways is not None:
        gws = report.get("gateways") or {}
        figures["gateways"] = {k: g.get("sessions") for k, g in gws.items()}
        if len(gws) != gateways:
            fails.append(f"{len(gws)} gateways in the report ({sorted(gws)}), expected {gateways}")
        for k, g in gws.items():
            sessions = g.get("sessions") or {}
            if not sessions.get("router") or not sessions.get("peer"):
                fails.append(f"{k}: sessions {sessions}: expected a router link and UAV peers")
    return fails, figures


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("report_dir", type=Path)
    p.add_argument("--impaired", default=None, help="the UAV whose uplink was impaired, e.g. uav2")
    p.add_argument("--delay-ms", type=float, default=0.0, help="the delay added on that link, ms")
    p.add_argument("--gateways", type=int, default=None, help="the number of gateways (sites) the run had")
    p.add_argument("--json", type=Path, default=None, help="write the figures here")
    a = p.parse_args(argv)
    try:
        report = json.loads((a.report_dir / "report.json").read_text())
        record = json.loads((a.report_dir / "record.json").read_text())
    except (OSError, ValueError) as e:
        print(f"compose check: cannot read the report in {a.report_dir}: {e}", file=sys.stderr)
        return 1
    fails, figures = check(report, record, a.impaired, a.delay_ms, a.gateways)
    print("compose check: " + json.dumps(figures))
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(figures, indent=1))
    for f in fails:
        print(f"compose check: FAIL {f}", file=sys.stderr)
    return 1 if fails else 0


if __name__ == "__main__":
    raise SystemExit(main())
