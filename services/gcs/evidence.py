"""Evidence for the verdict: a capture counts as imaged only on a report the detector can stand behind.

Design notes: docs/report.md (services/gcs/evidence.py).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable

from protocol.messages import DefectReport, LinkStats, VehicleState
from protocol.rtp import ssrc_for
from protocol.textsafe import md_text
from services.recording.witness import CAPTURE_CAMERA, FrameWitness, Seen


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


def sort_reports(reports: Iterable[DefectReport], witness: FrameWitness | None = None
                 ) -> tuple[dict[Seen, set[tuple[int, int]]], Counter[int]]:
    """The ok reports' ``(uav, capture_id)`` by what the ground station holds of the frame each names
    (:class:`~services.recording.witness.Seen`; without ``witness`` every evidenced report is held), a capture
    held by one report not listed as anything else; and per UAV the ok reports that name no frame."""
    by: dict[Seen, set[tuple[int, int]]] = {s: set() for s in Seen}
    unevidenced: Counter[int] = Counter()
    for r in reports:
        if not r.ok:
            continue
        if not has_evidence(r) or r.frame is None:
            unevidenced[r.uav] += 1
            continue
        by[Seen.HELD if witness is None else witness.seen(r.frame, r.capture_id)].add((r.uav, r.capture_id))
    for s in (Seen.NOT_RECEIVED, Seen.DIFFERENT, Seen.NO_SURFACE):
        by[s] -= by[Seen.HELD]
    return by, unevidenced


def no_surface_reasons(reports: Iterable[DefectReport], witness: FrameWitness) -> dict[tuple[int, int], str]:
    """``(uav, capture_id)`` -> why, of every evidenced report on a frame the ground station's own look found no
    surface in (:attr:`~services.recording.witness.Seen.NO_SURFACE`): the verdict's reason beside the capture."""
    out = {}
    for r in reports:
        if has_evidence(r) and r.frame is not None:
            why = witness.no_surface_reason(r.frame, r.capture_id)
            if why is not None:
                out[(r.uav, r.capture_id)] = f"reported ok, but its frame shows no surface: {why}"
    return out


def held_captures(reports: Iterable[DefectReport], witness: FrameWitness) -> set[tuple[int, int]]:
    """``(uav, capture_id)`` of every ok report whose frame the ground station received as named."""
    return sort_reports(reports, witness)[0][Seen.HELD]


def ledger(uavs: Iterable[int], states: Iterable[VehicleState], reports: Iterable[DefectReport],
           stats: Iterable[LinkStats], witness: FrameWitness | None = None) -> dict[int, dict[str, int | None]]:
    """Per UAV: ``sent`` (its capture count), ``received``/``analysed`` (the detector; None without
    statistics), ``reported`` (distinct evidenced captures), ``unevidenced`` (ok reports without evidence) and,
    checked against ``witness`` (the capture frames the ground station received itself; None: not checked,
    every evidenced report counts), ``not_received``, ``different`` and ``no_surface`` (distinct captures whose
    reports name a frame it never received, one with other image bytes or of another capture, or one its own
    look finds no surface in: not counted)."""
    uavs = list(uavs)
    sent = dict.fromkeys(uavs, 0)
    for s in states:
        if s.uav in sent:
            sent[s.uav] = max(sent[s.uav], s.captures)
    by, unevidenced = sort_reports(reports, witness)

    def count(seen: Seen, u: int) -> int:
        return sum(1 for uav, _ in by[seen] if uav == u)

    det = detector_totals(stats, uavs)
    return {u: {"sent": sent[u], "received": None if det is None else det[u]["received"],
                "analysed": None if det is None else det[u]["analysed"], "reported": count(Seen.HELD, u),
                "unevidenced": unevidenced[u],
                "not_received": None if witness is None else count(Seen.NOT_RECEIVED, u),
                "different": None if witness is None else count(Seen.DIFFERENT, u),
                "no_surface": None if witness is None else count(Seen.NO_SURFACE, u)}
            for u in uavs}


def corroboration_failures(book: dict[int, dict[str, int | None]]) -> list[str]:
    """Why the reports of a UAV cannot be trusted, one line per UAV (empty: every report is corroborated)."""
    out = []
    for u, row in sorted(book.items()):
        n = row["reported"] or 0
        if row["unevidenced"]:
            out.append(f"UAV {u}: {row['unevidenced']} defect report(s) name no frame of its camera (no SSRC, "
                       "sequence and digest): not counted")
        if row.get("not_received"):
            out.append(f"UAV {u}: {row['not_received']} capture(s) reported on a frame the ground station never "
                       "received (its log has no frame of that camera with that sequence number): not counted")
        if row.get("different"):
            out.append(f"UAV {u}: {row['different']} capture(s) reported on a frame other than the one the ground "
                       "station received (image digest or capture id differ): not counted")
        if row.get("no_surface"):
            out.append(f"UAV {u}: {row['no_surface']} capture(s) reported ok on a frame that shows no surface (black, "
                       "white or blank to the ground station's own look): not counted")
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
               "captures reported on a frame the ground station received itself (same image bytes, same capture), "
               "ok reports naming no frame, and captures reported on a frame it never received, on other bytes or ok "
               "on a frame that shows no surface (none of these four counted; '-': not checked, no mission log).", "",
               "| UAV | sent | received | analysed | reported | unevidenced | frame not received | frame differs "
               "| no surface |",
               "|---|---|---|---|---|---|---|---|---|"]
        for u, row in sorted(record.imagery.items()):
            md.append("| " + " | ".join(str(x) for x in (u, *("-" if row.get(k) is None else row[k] for k in
                      ("sent", "received", "analysed", "reported", "unevidenced", "not_received", "different",
                       "no_surface"))))
                      + " |")
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
