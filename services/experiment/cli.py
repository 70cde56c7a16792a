"""``skynet experiment``: the mission over a grid of link conditions; a table and plots of what held up.

Design notes: docs/experiments.md (services/experiment/cli.py).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from functools import partial
from pathlib import Path
from typing import Any

from protocol.cliconfig import add_options, from_namespace

from .config import ExperimentConfig
from .grid import Cell, Run, expand, impair_spec, mission_command, plan
from .metrics import METRICS, aggregate
from .runner import RunResult, run_all

REPO = Path(__file__).resolve().parents[2]


def build_parser() -> argparse.ArgumentParser:
    """``skynet experiment``'s command line: the options of :class:`ExperimentConfig`."""
    return add_options(argparse.ArgumentParser(prog="skynet experiment", description=__doc__.split("\n\n")[0]),
                       ExperimentConfig)


def grid_of(args: ExperimentConfig) -> tuple[list[Cell], list[Run]]:
    """The grid's cells and the runs that fly them."""
    cells = expand(args.loss, args.delay, args.jitter, args.recovery)
    return cells, plan(cells, args.repeat, args.seed)


#: what an impairment of the best-effort class is, by mode (results.md and the run's first line)
MODE = {False: "Secure mode (the default): every link class is a TLS stream (through a TCP proxy where impaired), so "
               "loss on the best-effort class is retransmission delay, not lost datagrams (`--insecure` for datagram "
               "loss).",
        True: "Insecure mode (`--insecure`): the best-effort class is plain UDP, so loss on it drops datagrams; no "
              "TLS, no access control, unsigned commands."}


def command_of(args: ExperimentConfig, run: Run, folder: Path) -> list[str]:
    """The mission command of ``run`` under the options (what is flown, and what --dry-run prints)."""
    return mission_command(run, str(folder), links=args.links, speed=args.speed, uavs=args.uavs, scenario=args.scenario,
                           insecure=args.insecure, mission=flown_with(args))


def flown_with(args: ExperimentConfig) -> list[str]:
    """The mission options every run shares beyond the grid's: the detector's method and the vehicle."""
    out = ["--method", args.method, "--vehicle", args.vehicle]
    return out + ["--flight", args.flight] if args.vehicle == "mavlink" else out


def summarise(args: ExperimentConfig, cells: list[Cell], results: list[RunResult], started: float,
              interrupted: bool = False) -> dict[str, Any]:
    """results.json's content."""
    rows = []
    for cell in cells:
        mine = [r.as_dict() for r in results if r.run.cell == cell]
        if mine:
            rows.append({"cell": cell.as_dict(), "name": cell.name, "label": cell.label,
                         "impair": impair_spec(cell, args.links), **aggregate(mine)})
    return {
        "experiment": {"loss_pct": sorted({c.loss_pct for c in cells}), "delay_ms": sorted({c.delay_ms for c in cells}),
                       "jitter_ms": sorted({c.jitter_ms for c in cells}),
                       "recovery": sorted({c.recovery for c in cells}, reverse=True), "repeat": args.repeat,
                       "seed": args.seed, "links": args.links, "speed": args.speed, "uavs": args.uavs,
                       "insecure": args.insecure, "method": args.method, "vehicle": args.vehicle,
                       "flight": args.flight if args.vehicle == "mavlink" else None,
                       "scenario": args.scenario, "timeout_s": args.timeout, "started": started,
                       "ended": time.time(), "interrupted": interrupted,
                       "runs_planned": len(cells) * args.repeat, "runs_done": len(results)},
        "metrics": {k: {"unit": u, "description": d} for k, (u, d) in METRICS.items()},
        "cells": rows,
        "runs": [r.as_dict() for r in results],
    }


def write_results(doc: dict[str, Any], out: Path) -> str:
    """results.json, results.md and the plots; returns the table."""
    from .plots import write_plots
    from .table import markdown

    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(doc, indent=1))
    table = markdown(doc["cells"])
    e = doc["experiment"]
    plots = write_plots(doc["cells"], out) if doc["cells"] else []
    flown = f"detector method `{e['method']}`, vehicle `{e['vehicle']}`" + (
        f" in {e['flight']}" if e.get("flight") else "")
    md = [
        "# Experiment: the mission under impaired links", "",
        (f"Impaired links: `{e['links']}` (from 2 s after each proxy starts); speed x{e['speed']:g}, "
         f"{e['uavs']} UAVs, {e['repeat']} run(s) per cell, seeds {e['seed']}..{e['seed'] + e['repeat'] - 1}; "
         f"{flown}; "
         f"{e['runs_done']} of {e['runs_planned']} runs done{' (interrupted)' if e['interrupted'] else ''}."), "",
        MODE[bool(e.get("insecure"))], "",
        table, "",
        "Figures are means over the runs of a cell, with (min-max) when they differ. Definitions:", "",
        *[f"- `{k}`: {d}{f' ({u})' if u else ''}" for k, (u, d) in METRICS.items()],
        ("- *missing*: capture frames that never reached the detector (planned - delivered - late); *lost (gaps)*: "
         "sequence numbers its jitter buffer gave up (RFC 3550 loss, which cannot see a stream's first or last "
         "frames); *late*: frames that arrived after their number was given up (still analysed); *recovered*: "
         "frames the live best-effort path lost that reached the detector through recovery (the cameras' caches)."),
        "",
        *[f"![{p}]({p})" for p in plots],
    ]
    (out / "results.md").write_text("\n".join(md) + "\n")
    return table


def run_experiment(args: ExperimentConfig, cells: list[Cell], runs: list[Run], out: Path,
                   echo=None) -> tuple[dict[str, Any], int]:
    """Fly every run, write the results; (results.json content, exit status). ``echo``: default stdout."""
    echo = echo or sys.stdout
    started = time.time()
    results: list[RunResult] = []

    def progress(res: RunResult, i: int, n: int) -> None:
        results.append(res)
        m = res.metrics
        cov = m.get("coverage")
        print(f"[{i + 1}/{n}] {res.run.cell.label}, seed {res.run.seed}: {res.status}, "
              f"success {int(m.get('success') or 0)}, coverage {'-' if cov is None else f'{100 * cov:.0f}%'}, "
              f"{res.wall_s:.0f} s", file=echo, flush=True)

    interrupted = False
    try:
        run_all(runs, partial(command_of, args), out, args.timeout, on_result=progress, cwd=str(REPO))
    except KeyboardInterrupt:
        interrupted = True
        print("interrupted: writing what ran", file=echo, flush=True)
    doc = summarise(args, cells, results, started, interrupted)
    table = write_results(doc, out)
    print("\n" + table + "\n", file=echo)
    print(f"results: {out / 'results.md'} (and results.json, plots)", file=echo, flush=True)
    if interrupted:
        return doc, 130
    return doc, 0 if all(r.status == "ok" for r in results) else 1


def main(argv: list[str] | None = None) -> int:
    """``skynet experiment``: parse the command line, then :func:`run` the grid."""
    parser = build_parser()
    return run(from_namespace(ExperimentConfig, parser.parse_args(argv), parser))


def run(args: ExperimentConfig) -> int:
    """The experiment of a configuration (``--dry-run``: its commands printed); the exit status."""
    cells, runs = grid_of(args)
    out = Path(args.out or f"reports/experiment-{time.strftime('%Y%m%d-%H%M%S')}")
    if args.dry_run:
        for r in runs:
            print(shlex.join(command_of(args, r, out / "runs" / r.name)))
        return 0
    print(f"{len(runs)} runs ({len(cells)} cells x {args.repeat}) into {out}. {MODE[args.insecure]}", flush=True)
    return run_experiment(args, cells, runs, out)[1]


if __name__ == "__main__":
    raise SystemExit(main())
