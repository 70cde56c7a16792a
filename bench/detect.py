"""Detector benchmark: parameter choice, quality table on both crack data sets, speed.

    python bench/detect.py [--data DIR] [--only tune|quality|speed ...] [--repeats N]
                           [--threads N] [--out bench/results/detect.json]

* tune     C_s of IT for both background readings, and IT+'s area guard and shape limits, on
           the DeepCrack *training* split only (the numbers behind the module defaults).
* quality  Table II-style scores of every method on crackforest/ and deepcrack-train/.
* speed    IT vs OpenCV's Otsu (cv2.threshold + THRESH_OTSU), and IT+, side by side on the same
           BGR frames at 480x320 and 4000x3000, grey conversion and mask output included,
           OpenCV limited to ``--threads`` (default 1: "one core").

Prints Markdown tables and writes all numbers as JSON (bench/results/ is git-ignored).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from services.detector.detect import METHODS, detect  # noqa: E402
from services.detector.evaluate import evaluate, load_dataset, markdown_table  # noqa: E402
from services.detector.improved import it_plus_mask, shape_filter, threshold_it_plus  # noqa: E402
from services.detector.iterative import C_S_DEFAULT, iterative_threshold  # noqa: E402
from services.detector.metrics import f_measure  # noqa: E402
from services.detector.thresholds import histogram  # noqa: E402

DEFAULT_DATA = Path("/work/shared/data")
SETS = ("crackforest", "deepcrack-train")


# ------------------------------------------------------------------------------------------ tune
def tune(data: Path) -> dict[str, object]:
    samples = load_dataset(data / "deepcrack-train")
    hists = [histogram(s.grey) for s in samples]
    gts = [s.mask for s in samples]
    out: dict[str, object] = {"dataset": "deepcrack-train", "n_images": len(samples)}

    def f_at(ts: list[int]) -> np.ndarray:
        return np.array([f_measure(s.grey <= t, g)[0] for s, t, g in zip(samples, ts, gts)])

    grid = [round(x, 3) for x in np.arange(0.10, 0.601, 0.025)]
    print("\n### IT: C_s on DeepCrack train (mean defect-class F, exact pixels)\n")
    print("| C_s | above | previous |\n|---|---|---|")
    table: dict[str, dict[str, float]] = {}
    per: dict[tuple[str, float], np.ndarray] = {}
    for cs in grid:
        row = {}
        for bg in ("above", "previous"):
            f = f_at([iterative_threshold(hist=h, c_s=cs, background=bg).threshold for h in hists])
            per[(bg, cs)] = f
            row[bg] = float(f.mean())
        table[str(cs)] = row
        print(f"| {cs:.3f} | {row['above']:.4f} | {row['previous']:.4f} |")
    best = {bg: max(grid, key=lambda c: table[str(c)][bg]) for bg in ("above", "previous")}
    b = best["above"]
    # smallest C_s whose mean F is within one standard error (paired) of the best one
    within = [c for c in grid if (per[("above", b)] - per[("above", c)]).mean()
              <= (per[("above", b)] - per[("above", c)]).std(ddof=1) / np.sqrt(len(hists)) + 1e-12]
    one_se = min(within)
    print(f"\nbest: above C_s={best['above']} (F={table[str(best['above'])]['above']:.4f}), "
          f"previous C_s={best['previous']} (F={table[str(best['previous'])]['previous']:.4f}); "
          f"one-SE choice (above): C_s={one_se}; module default C_S_DEFAULT={C_S_DEFAULT}")
    out["it_cs_grid"] = table
    out["it_best"] = best
    out["it_one_se"] = one_se

    print("\n### IT+: area guard and shape limits on DeepCrack train (C_s = C_S_DEFAULT)\n")
    print("| min_fraction | min_area | min_elongation | min_length | F |\n|---|---|---|---|---|")
    rows = []
    shapes = [(0, 0, 0), (20, 6, 30), (30, 8, 40), (60, 10, 60)]
    for mf in (0.0, 0.01, 0.015, 0.02, 0.025, 0.03, 0.04):
        ts = [threshold_it_plus(hist=h, c_s=C_S_DEFAULT, min_fraction=mf) for h in hists]
        raws = [cv2.threshold(s.grey, t, 255, cv2.THRESH_BINARY_INV)[1] for s, t in zip(samples, ts)]
        for a, e, ln in shapes:
            masks = raws if a == 0 else [
                shape_filter(r, min_area=a, min_elongation=e, min_length=ln) for r in raws]
            f = float(np.mean([f_measure(m, g)[0] for m, g in zip(masks, gts)]))
            rows.append({"min_fraction": mf, "min_area": a, "min_elongation": e, "min_length": ln, "f": f})
            print(f"| {mf} | {a} | {e} | {ln} | {f:.4f} |")
    top = max(rows, key=lambda r: r["f"])
    print(f"\nbest IT+ setting: {top}")
    out["it_plus_grid"] = rows
    out["it_plus_best"] = top
    return out


# --------------------------------------------------------------------------------------- quality
def quality(data: Path) -> dict[str, object]:
    out: dict[str, object] = {}
    for name in SETS:
        folder = data / name
        if not folder.is_dir():
            print(f"\n(skipping {name}: {folder} not found)")
            continue
        ev = evaluate(load_dataset(folder), list(METHODS), dataset=name)
        print("\n" + markdown_table(ev))
        m = ev.mean
        goals = {
            "it_beats_otsu_ve_itth_sdd": all(m["it"]["f"] > m[k]["f"] for k in ("otsu", "ve", "itth", "sdd")),
            "it_plus_beats_it": m["it+"]["f"] > m["it"]["f"],
        }
        print(f"\ngoals on {name}: {goals}")
        out[name] = {"mean": m, "goals": goals, "per_image": ev.per_image, "images": ev.names}
    return out


# ----------------------------------------------------------------------------------------- speed
def _frame(data: Path, size: tuple[int, int]) -> np.ndarray:
    src = data / "crackforest" / "images" / "001.jpg"
    img = cv2.imread(str(src), cv2.IMREAD_COLOR) if src.exists() else None
    if img is None:  # no data: a synthetic cracked surface
        from edge.surface import crack_image

        g, _ = crack_image((320, 480), np.random.default_rng(0))
        img = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
    return cv2.resize(img, size, interpolation=cv2.INTER_CUBIC)


def _otsu_cv2(bgr: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    return cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)[1]


def _it(bgr: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    t = iterative_threshold(hist=histogram(grey)).threshold
    return cv2.threshold(grey, t, 255, cv2.THRESH_BINARY_INV)[1]


def _it_plus(bgr: np.ndarray) -> np.ndarray:
    return it_plus_mask(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))[0]


def _it_plus_defects(bgr: np.ndarray) -> np.ndarray:
    return detect(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), "it+").mask


def speed(data: Path, repeats: int, threads: int) -> dict[str, object]:
    cv2.setNumThreads(threads)
    fns = {"otsu (cv2)": _otsu_cv2, "it": _it, "it+": _it_plus, "it+ with defect list": _it_plus_defects}
    out: dict[str, object] = {"cv2_threads": threads, "repeats": repeats,
                              "cpu": platform.processor() or platform.machine()}
    print(f"\n### Speed (OpenCV threads = {threads}; median over {repeats} interleaved blocks "
          "of >= 10 ms; BGR in, mask out)\n")
    print("| size | method | ms/frame (median) | fps | vs Otsu |\n|---|---|---|---|---|")
    for w, h in ((480, 320), (4000, 3000)):
        bgr = _frame(data, (w, h))
        times: dict[str, list[float]] = {k: [] for k in fns}
        loops = {}
        for k, f in fns.items():  # warm-up, and calls per timed block (blocks of >= ~10 ms)
            t0 = time.perf_counter()
            f(bgr)
            loops[k] = max(1, int(0.01 / max(time.perf_counter() - t0, 1e-6)))
        for _ in range(repeats):  # interleaved blocks: every method sees the same machine load
            for k, f in fns.items():
                t0 = time.perf_counter()
                for _ in range(loops[k]):
                    f(bgr)
                times[k].append((time.perf_counter() - t0) * 1e3 / loops[k])
        med = {k: float(np.median(v)) for k, v in times.items()}
        key = f"{w}x{h}"
        out[key] = {k: {"ms_median": med[k], "ms_p90": float(np.percentile(times[k], 90)),
                        "fps": 1e3 / med[k], "ratio_to_otsu": med[k] / med["otsu (cv2)"]}
                    for k in fns}
        for k in fns:
            print(f"| {key} | {k} | {med[k]:.2f} | {1e3 / med[k]:.0f} | {med[k] / med['otsu (cv2)']:.2f}x |")
    big = out["4000x3000"]
    out["goals"] = {
        "it_at_most_2x_otsu_480": out["480x320"]["it"]["ratio_to_otsu"] <= 2.0,  # type: ignore[index]
        "it_at_most_2x_otsu_12mp": big["it"]["ratio_to_otsu"] <= 2.0,  # type: ignore[index]
        "it_30fps_12mp": big["it"]["fps"] >= 30,  # type: ignore[index]
        "it_plus_20fps_12mp": big["it+"]["fps"] >= 20,  # type: ignore[index]
    }
    print(f"\ngoals: {out['goals']}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder holding the data sets")
    ap.add_argument("--only", nargs="+", choices=("tune", "quality", "speed"),
                    default=["tune", "quality", "speed"])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--threads", type=int, default=1, help="cv2.setNumThreads for the speed runs")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "detect.json")
    a = ap.parse_args(argv)
    has_data = all((a.data / s).is_dir() for s in SETS)
    res: dict[str, object] = {}
    if "tune" in a.only or "quality" in a.only:
        if not has_data:
            print(f"data sets not found under {a.data}: skipping tune and quality")
        else:
            if "tune" in a.only:
                res["tune"] = tune(a.data)
            if "quality" in a.only:
                res["quality"] = quality(a.data)
    if "speed" in a.only:
        res["speed"] = speed(a.data, a.repeats, a.threads)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1))
    print(f"\nwrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
