"""The mission report's Markdown page (figures -> Markdown): the paper's results section re-told.

Design notes: docs/report.md (services/gcs/markdown.py).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from protocol.textsafe import md_text
from services.gcs.evidence import integrity_markdown
from services.gcs.figures import ReportSummary
from services.gcs.resilience import GAP_S
from services.recording.record import MissionRecord

__all__ = ["markdown"]


def _fmt(x: Any, nd: int = 2, unit: str = "") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:.{nd}f}{unit}"
    return f"{x}{unit}"


def _table(head: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A GFM table; every cell is literal text (:func:`protocol.textsafe.md_text`): a cell holding text from
    another node (an event's, a refusal's) stays one cell of one row, its HTML and Markdown inert."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(md_text(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def markdown(record: MissionRecord, s: ReportSummary) -> str:
    """The text of ``report.md`` for the figures ``s`` of ``record``."""
    md: list[str] = [f"# Mission report: fleet `{s.fleet}`", ""]
    outcome = "**success**" if s.success else "**failed**"
    md += [f"Outcome: {outcome}" + (f" ({'; '.join(md_text(f) for f in s.failures)})" if s.failures else "") + ".", ""]
    md += [f"> Note: {md_text(n)}." for n in s.notes] + ([""] if s.notes else [])
    scen = record.scenario.name if record.scenario else "–"
    md += ["## Experimental setup", "",
           _table(["item", "value"], [
               ["scenario", scen],
               ["UAVs", ", ".join(str(u) for u in s.uavs) or "–"],
               ["mission wall time", _fmt(s.wall_time_s, 1, " s")],
               ["simulation speed factor (set / measured)", f"{_fmt(s.speed)} / {_fmt(s.measured_speed)}"],
               ["simulated time covered by the states", _fmt(s.sim_time_s, 1, " s")],
               ["obstacles", str(len(record.scenario.obstacles) if record.scenario else 0)],
               ["formation offsets ΔT_n (P9)", "; ".join(f"UAV {u}: {tuple(o)}" for u, o in s.formation.offsets.items())
                or "–"],
           ]), ""]
    md += ["## High-level control results", "", "### Path planning (cf. Table I)", ""]
    p = s.planner
    if p is not None:
        md += [_table(["algorithm", "initial cost", "min cost", "iterations to converge", "iterations",
                       "planning time", "plan request", "collision free"],
                      [[p.algorithm, _fmt(p.initial_cost), _fmt(p.cost), _fmt(p.convergence_iteration), p.iterations,
                        _fmt(p.planning_time_s, 2, " s"), _fmt(p.plan_request_s, 2, " s"), _fmt(p.collision_free)],
                       ["θ-PSO (paper, Table I)", "142.84", "111.02", "68", "300", "–", "–", "–"]]),
               "", "The paper's costs come from its own cost weights and obstacles, so only the shape of the "
               "convergence compares, not the values.", "", "![Planner convergence](convergence.png)", ""]
    else:
        md += ["No plan was received.", ""]
    md += ["### Formation flight", "",
           "![Trajectories of the UAVs tracking the planned paths](trajectories.png)", "",
           "![Altitudes of the UAVs](altitudes.png)", "",
           "![Errors between the planned and flown paths](path_error.png)", "",
           "Path error: distance from each flown position (while tracking) to the planned path; "
           "time-aligned: to the planned position at the same trajectory time.", "",
           _table(["UAV", "reached goal", "distance to goal", "flown (all / tracking)", "planned length",
                   "path error RMS / max", "time-aligned RMS / max", "captures imaged / planned"],
                  [[u, _fmt(f.reached_goal), _fmt(f.goal_distance_m, 2, " m"),
                    f"{_fmt(f.path_length_m, 1)} / {_fmt(f.mission_length_m, 1)} m", _fmt(f.planned_length_m, 1, " m"),
                    f"{_fmt(f.path_error_rms_m)} / {_fmt(f.path_error_max_m)} m",
                    f"{_fmt(f.time_error_rms_m)} / {_fmt(f.time_error_max_m)} m",
                    f"{f.captures_imaged} / {f.captures_planned}"] for u, f in s.uavs.items()]), "",
           "![Formation error](formation_error.png)", "",
           f"Formation shape error over the MISSION phase ({s.formation.samples} samples, "
           f"{_fmt(s.formation.duration_s, 1)} s): RMS {_fmt(s.formation.rms_m)} m, max {_fmt(s.formation.max_m)} m "
           f"(the plan itself, measured the same way: RMS {_fmt(s.formation.plan_rms_m)} m, "
           f"max {_fmt(s.formation.plan_max_m)} m).",
           ""]
    md += ["## Surface inspection results", ""]
    c = s.captures
    how = "on a frame the ground station received itself" if c.checked else \
        "not checked against the frames the ground station received (no mission log)"
    md += [f"Captures imaged (a report came back, {how}): {c.imaged} of {c.planned} planned"
           + (f" ({100 * c.ratio:.1f} %)" if c.ratio is not None else "")
           + f"; failed reports: {c.failed_reports}; reports for unplanned captures: {c.unplanned_reports}.", ""]
    d = s.defects
    if d is not None and d.n_truth == 0:
        md += [f"No ground truth for this run (real or replayed imagery): {d.n_reported + d.without_pos} defects "
               f"reported, {d.without_pos} of them without a surface position; recall and precision are not "
               "defined.", ""]
    elif d is not None:
        md += [_table(["ground-truth cracks", "found", "reported positions", "on a crack", "without position",
                       "recall", "precision", "F (P20, objects)"],
                      [[d.n_truth, d.n_found, d.n_reported, d.n_true, d.without_pos, _fmt(d.recall), _fmt(d.precision),
                        _fmt(d.f_measure)]]),
               "", f"A reported position counts when it lies within {d.tolerance_m:g} m of a crack's bounding box "
               "on the surface.", ""]
    else:
        md += ["No defect score (no ground truth and no defect reports, or nowhere to place them).", ""]
    md += ["![Defects on the surface](defects_map.png)", ""]
    md += ["## Communication", "",
           _table(["flow", "carried as", "delivered / sent", "ratio", "latency", "p50", "p95", "p99", "n"],
                  [[k, lf.carried_as, f"{lf.delivered} / {lf.sent}" if lf.sent else str(lf.delivered),
                    _fmt(lf.ratio, 4), lf.latency_kind, _fmt(lf.latency_ms.p50, 1, " ms"),
                    _fmt(lf.latency_ms.p95, 1, " ms"), _fmt(lf.latency_ms.p99, 1, " ms"), lf.latency_ms.n]
                   for k, lf in s.links.items()]), ""]
    if s.imagery:
        keys = ["received", "lost", "fraction_lost", "reordered", "late", "duplicated", "jitter_ms"]
        md += ["Imagery per camera (detector jitter buffer, RFC 3550):", "",
               _table(["camera", *keys], [[cam, *(_fmt(m.get(k), 3 if k in ("fraction_lost", "jitter_ms") else 0)
                                                   for k in keys)] for cam, m in s.imagery.items()]), ""]
    md += ["![Latency per link class](links.png)", ""]
    md += _faults_markdown(s.faults)
    md += ["## Events", ""]
    if s.events:
        md += [_table(["rx", "source", "level", "kind", "text"],
                      [[_fmt(e["rx"] - s.started, 2, " s"), e["source"], e["level"], e["kind"],
                        e["text"]] for e in s.events]), ""]
    else:
        md += ["No events.", ""]
    if len(record.events) > len(s.events):
        md += [f"{len(record.events) - len(s.events)} more events are in record.json / mission.mcap.", ""]
    if len(s.gateways) > 1:  # one gateway per site: each one's sessions and traffic
        md += ["## Gateways", "", _table(
            ["gateway", "sessions", "samples", "MB", "rejected"],
            [[src, ", ".join(f"{k} {v}" for k, v in sorted(g["sessions"].items())),
              str(sum(c["samples"] for c in g["classes"].values())),
              _fmt(sum(c["bytes"] for c in g["classes"].values()) / 1e6, 2),
              str(sum(g["rejected"].values()))] for src, g in s.gateways.items()]), ""]
    for src, g in s.gateways.items():
        if g["rejected"]:
            where = f" ({src})" if len(s.gateways) > 1 else ""
            md += [f"Gateway rejections{md_text(where)}: "
                   + ", ".join(f"{md_text(k)}: {v}" for k, v in g["rejected"].items()) + ".", ""]
    md += integrity_markdown(record)
    return "\n".join(md)


def _faults_markdown(f: Mapping[str, Any]) -> list[str]:
    """The "Faults and recovery" section (figures of :func:`services.gcs.resilience.fault_figures`)."""
    md = ["## Faults and recovery", ""]
    if not f:
        return md + ["No record of faults.", ""]
    cmds = f["commands"]
    supervision, missed = f.get("supervision") or [], f.get("not_injected") or []
    quiet = not (f["faults"] or supervision or missed or f["uavs_lost"] or f["failsafes"] or f["resumes"] or f["gcs_link"] or cmds["failed"]
                 or f["skynet"])
    if quiet:
        return md + [f"No fault injected or seen; {cmds['acknowledged']} of {cmds['sent']} commands acknowledged.", ""]
    md += [f"Times in seconds since the {f['origin']}.", ""]
    if f["faults"]:
        md += ["Faults injected:", "", _table(["t", "action", "target", "as written"],
                                             [[_fmt(x["t_s"], 1, " s"), x["action"], x["target"], x["text"]]
                                              for x in f["faults"]]), ""]
    else:
        md += ["No fault injected.", ""]
    if missed:
        md += ["Scheduled and never injected (the mission ended first): " + "; ".join(md_text(x) for x in missed) + ".", ""]
    if supervision:
        md += ["The launcher's supervisor (not injected faults):", "",
               _table(["t", "what", "service", "detail"],
                      [[_fmt(x["t_s"], 1, " s"), "did not start" if x["action"] == "start-failed" else "restarted",
                        x["target"], x["text"]] for x in supervision]), ""]
    for x in f["seen_again"]:
        line = (f"{x['after'].capitalize()} of {x['target']} at {_fmt(x['t_s'], 1, ' s')} (down since "
                f"{_fmt(x['began_s'], 1, ' s')}): ")
        if x["uavs_s"]:
            line += (f"fleet seen again at {_fmt(x['fleet_seen_s'], 2, ' s')}, {_fmt(x['fleet_s'], 2, ' s')} after "
                     f"the {x['after']}, {_fmt(x['blackout_s'], 2, ' s')} of blackout ("
                     + ", ".join(f"UAV {u}: {_fmt(v, 2, ' s')}" for u, v in x["uavs_s"].items()) + ")")
            if x.get("heard_throughout"):
                line += "; heard throughout: " + ", ".join(f"UAV {u}" for u in x["heard_throughout"])
        elif x.get("heard_throughout"):
            line += f"the fleet was heard throughout (no gap in its states over {GAP_S:g} s)"
        else:
            line += "the fleet was not heard after it"
        if x["never"]:
            line += "; never heard again: " + ", ".join(f"UAV {u}" for u in x["never"])
        md += [line + ".", ""]
    if f["gcs_link"]:
        md += ["Ground station's link to the gateway: " + "; ".join(
            f"down at {_fmt(x['down_s'], 1, ' s')}, up at {_fmt(x['up_s'], 1, ' s')}" for x in f["gcs_link"]) + ".", ""]
    if f["uavs_lost"]:
        md += ["UAVs gone from liveliness:", "",
               _table(["UAV", "token gone", "counted lost", "back"],
                      [[x["uav"], _fmt(x["gone_s"], 1, " s"), _fmt(x["lost_s"], 1, " s"), _fmt(x["back_s"], 1, " s")]
                       for x in f["uavs_lost"]]), ""]
    if f["still_lost"]:
        md += ["Lost at the end (not waited for; their capture points not imaged): "
               + ", ".join(f"UAV {u}" for u in f["still_lost"]) + ".", ""]
    if f["failsafes"] or f["resumes"]:
        rows = [(x["t_s"], [x["uav"], "failsafe" + (f": {x['action']}" if x["action"] else ""),
                            f"no heartbeat for {_fmt(x['silent_s'], 1, ' s')}" if x["rx_s"] is not None
                            else "its event was lost with the link; time from its failsafe-cleared event"])
                for x in f["failsafes"]]
        rows += [(x["t_s"], [x["uav"], "resume" if x["ok"] else "resume failed",
                             f"{_fmt(x['after_failsafe_s'], 1, ' s')} after its failsafe"]) for x in f["resumes"]]
        md += ["Failsafes and resumes:", "", _table(["t", "UAV", "what", "detail"],
                                                    [[_fmt(tt, 1, " s"), *r] for tt, r in sorted(rows, key=lambda r: r[0])]),
               ""]
    if f["skynet"]:
        md += ["SkyNet (the boards' view of their neighbours):", "",
               _table(["t", "UAV", "event", "neighbour"],
                      [[_fmt(x["t_s"], 1, " s"), x["uav"], x["kind"], x["neighbour"]] for x in f["skynet"]]), ""]
    rec = f["reception"]
    if rec:
        md += ["State reception at the ground station:", "",
               _table(["UAV", "last heard", "longest gap", "ended at", "gaps > 1 s"],
                      [[u, _fmt(x["last_rx_s"], 1, " s"), _fmt(x["max_gap_s"], 2, " s"), _fmt(x["max_gap_ended_s"], 1, " s"),
                        ", ".join(f"{_fmt(a, 1)}–{_fmt(b, 1)} s" for a, b in x["gaps"]) or "none"]
                       for u, x in rec.items()]), ""]
    md += [f"Commands: {cmds['acknowledged']} of {cmds['sent']} acknowledged"
           + (", every one either acknowledged or listed here as failed:" if cmds["failed"] else "; none failed.")]
    if cmds["failed"]:
        md += ["", _table(["UAV", "command", "id", "acknowledged", "tries", "reason"],
                          [[x["uav"], x["kind"], x["cmd_id"], _fmt(x["acknowledged"]), x["attempts"],
                            x["reason"]] for x in cmds["failed"]])]
    return md + [""]
