"""Evidence for the verdict: a capture counts as imaged only on a report the detector can stand behind.

Design notes: docs/report.md (services/gcs/evidence.py).
"""

from __future__ import annotations

from collections.abc import Iterable

from protocol.messages import DefectReport, LinkStats, VehicleState
from protocol.rtp import ssrc_for
from protocol.textsafe import md_text

#: the camera whose frames are captures (edge.camera_service: previews use camera 1)
CAPTURE_CAMERA = 0


def has_evidence(report: DefectReport) -> bool:
    """An ok report that names a frame of the UAV's own capture camera."""
    return report.ok and report.frame is not None and report.frame.ssrc == ssrc_for(report.uav, CAPTURE_CAMERA)


def detector_totals(stats: Iterable[LinkStats], uavs: Iterable[int]) -> dict[int, dict[str, int]] | None:
    """Per UAV ``received`` and ``analysed`` frames of its capture camera over every detector run; None
    when there is no statistics message at all."""
    uavs = list(uavs)
    names = ("received", "analysed")
    totals = {u: dict.fromkeys(names, 0) for u in uavs}
    runs: dict[str, dict[int, dict[str, int]]] = {}  # instance (LinkStats.source) -> its current run
    last_uptime: dict[str, float] = {}
    for st in stats:
        run = runs.setdefault(st.source, {u: dict.fromkeys(names, 0) for u in uavs})
        last = last_uptime.get(st.source)
        if last is not None and st.uptime_s < last:  # that instance restarted: a new run
            for u in uavs:
                for n in names:
                    totals[u][n] += run[u][n]
                    run[u][n] = 0
        last_uptime[st.source] = st.uptime_s
        for u in uavs:
            for n in names:
                v = st.metrics.get(f"uav{u}.cam{CAPTURE_CAMERA}.{n}")
                if v is not None:
                    run[u][n] = max(run[u][n], int(v))
    if not runs:
        return None
    for run in runs.values():
        for u in uavs:
            for n in names:
                totals[u][n] += run[u][n]
    return totals


def ledger(uavs: Iterable[int], states: Iterable[VehicleState], reports: Iterable[DefectReport],
           stats: Iterable[LinkStats]) -> dict[int, dict[str, int | None]]:
    """Per UAV: ``sent`` (its capture count), ``received``/``analysed`` (the detector; None without
    statistics), ``reported`` (distinct evidenced captures) and ``unevidenced`` (ok reports without evidence)."""
    uavs = list(uavs)
    sent = dict.fromkeys(uavs, 0)
    for s in states:
        if s.uav in sent:
            sent[s.uav] = max(sent[s.uav], s.captures)
    reported: dict[int, set[int]] = {u: set() for u in uavs}
    unevidenced = dict.fromkeys(uavs, 0)
    for r in reports:
        if r.uav not in reported or not r.ok:
            continue
        if has_evidence(r):
            reported[r.uav].add(r.capture_id)
        else:
            unevidenced[r.uav] += 1
    det = detector_totals(stats, uavs)
    return {u: {"sent": sent[u], "received": None if det is None else det[u]["received"],
                "analysed": None if det is None else det[u]["analysed"], "reported": len(reported[u]),
                "unevidenced": unevidenced[u]} for u in uavs}


def corroboration_failures(book: dict[int, dict[str, int | None]]) -> list[str]:
    """Why the reports of a UAV cannot be trusted, one line per UAV (empty: every report is corroborated)."""
    out = []
    for u, row in sorted(book.items()):
        n = row["reported"] or 0
        if row["unevidenced"]:
            out.append(f"UAV {u}: {row['unevidenced']} defect report(s) name no frame of its camera (no SSRC, "
                       "sequence and digest): not counted")
        if not n:
            continue
        if row["analysed"] is None:
            out.append(f"UAV {u}: {n} capture(s) reported but no statistics were heard from the detector: "
                       "the reports are not corroborated (is the detector running?)")
        elif n > row["analysed"]:
            out.append(f"UAV {u}: {n} capture(s) reported but the detector analysed only {row['analysed']} frame(s) "
                       f"of its camera ({row['received']} received): the reports are not corroborated")
    return out


def integrity_markdown(record) -> list[str]:
    """The report's "Evidence and integrity" section: the imagery ledger per UAV, what the ground station
    refused (undecodable or over budget, protocol.budget) and any recording error (services.recording.record)."""
    md = ["## Evidence and integrity", ""]
    if record.imagery:
        md += ["Frames per UAV: sent by its camera, received and analysed by the detector (its statistics), "
               "captures reported with frame evidence, and ok reports without it (not counted).", "",
               "| UAV | sent | received | analysed | reported | unevidenced |", "|---|---|---|---|---|---|"]
        for u, row in sorted(record.imagery.items()):
            md.append("| " + " | ".join(str(x) for x in (u, *("-" if row[k] is None else row[k] for k in
                      ("sent", "received", "analysed", "reported", "unevidenced")))) + " |")
        md.append("")
    if record.rejected:
        top = sorted(record.rejected.items(), key=lambda kv: -kv[1])[:20]
        md += ["Refused by the ground station (key|reason: samples): "
               + ", ".join(f"{md_text(k)}: {v}" for k, v in top) + ".", ""]
    if record.not_kept:
        md += ["Not kept in memory (over the caps; in mission.mcap): "
               + ", ".join(f"{k}: {v}" for k, v in record.not_kept.items()) + ".", ""]
    for err in record.recording_errors:
        md += [f"**Recording:** {md_text(err)}", ""]
    if record.report_input and record.report_input not in record.recording_errors:
        md += [f"This report is computed from {md_text(record.report_input)}.", ""]
    return md
