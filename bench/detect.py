"""Detector benchmark: parameter choice, quality table on both crack data sets, speed.

    python bench/detect.py [--data DIR] [--only tune|ridge|quality|speed|learned|pool ...] [--repeats N]
                           [--threads N] [--candidate MODEL.onnx] [--out bench/results/detect.json]

* tune     C_s and the size guard min_region of IT for both background readings, and IT+'s
           area guard and shape limits, on the DeepCrack *training* split only (the numbers
           behind the module defaults).
* ridge    IT+r's parameters one at a time around its defaults, on DeepCrack-train and the
           odd-numbered half of CrackForest, with the even half held out.
* quality  Table II-style scores of every method on crackforest/ and deepcrack-train/, and
           IT's mean F over C_s on both (a diagnostic; nothing is chosen from it).
* speed    IT vs OpenCV's Otsu (cv2.threshold + THRESH_OTSU), and IT+, side by side on the same
           BGR frames at 480x320 and 4000x3000, grey conversion and mask output included,
           OpenCV limited to ``--threads`` (default 1: "one core").
* learned  the learned method (a small U-Net, services/detector/learned.py) beside IT+r on its
           held-out folds (quality) and at 640x480 and a 12 MP capture's 1/4 decode (speed).
* pool     the detector's worker pool (services/detector/pool.py, two workers) analysing the nominal
           mission's own 640x480 captures in bursts of three (three UAVs shooting together), learned
           and IT+r, with one OpenCV thread per worker and with OpenCV's default (one per core):
           per-frame latency (submit to report) and each worker's CPU ms per frame.

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
from services.detector.improved import it_plus_bh_mask, it_plus_mask, shape_filter, threshold_it_plus  # noqa: E402
from services.detector.iterative import C_S_DEFAULT, C_S_UNGUARDED, MIN_REGION_DEFAULT, iterative_threshold  # noqa: E402
from services.detector.metrics import f_measure  # noqa: E402
from services.detector.ridge import RIDGE_DEFAULTS, it_plus_ridge_mask  # noqa: E402
from services.detector.thresholds import histogram  # noqa: E402

DEFAULT_DATA = Path("/work/shared/data")
SETS = ("crackforest", "deepcrack-train")
SENS_GRID = [float(round(x, 3)) for x in np.arange(0.10, 0.601, 0.025)]


# ------------------------------------------------------------------------------------------ tune
def _f_curves(samples: list) -> np.ndarray:
    """Exact defect-class F (P20) of ``grey <= t`` for every t = -1..255: row i, column t + 1.

    From two cumulative histograms per image (all pixels, ground-truth pixels): the same numbers
    as :func:`services.detector.metrics.f_measure` on every threshold, without 257 masks.
    """
    out = np.empty((len(samples), 257))
    for i, s in enumerate(samples):
        n_pred = np.concatenate([[0.0], np.cumsum(histogram(s.grey))])
        tp = np.concatenate([[0.0], np.cumsum(histogram(s.grey, s.mask))])
        n_gt = float(np.count_nonzero(s.mask))
        den = n_pred + n_gt
        out[i] = np.where(den > 0, 2 * tp / np.where(den > 0, den, 1.0), 1.0)
    return out


def _one_se(per: dict[tuple[float, float], np.ndarray]) -> tuple[tuple[float, float], list]:
    """Best key by mean, and every key within one paired standard error of it."""
    best = max(per, key=lambda k: per[k].mean())
    n = len(per[best])
    se = {k: (per[best] - per[k]).std(ddof=1) / np.sqrt(n) for k in per}
    within = [k for k in per if (per[best] - per[k]).mean() <= se[k] + 1e-12]
    return best, within


def tune(data: Path) -> dict[str, object]:
    samples = load_dataset(data / "deepcrack-train")
    hists = [histogram(s.grey) for s in samples]
    gts = [s.mask for s in samples]
    curves = _f_curves(samples)
    rows_i = np.arange(len(samples))
    out: dict[str, object] = {"dataset": "deepcrack-train", "n_images": len(samples)}

    regions = (0.0, 0.005, 0.01, 0.015, 0.02, 0.025, 0.03, 0.035, 0.04, 0.05, 0.07, 0.1)
    grid = [float(round(x, 3)) for x in np.arange(0.20, 0.651, 0.025)]
    per: dict[str, dict[tuple[float, float], np.ndarray]] = {"above": {}, "previous": {}}
    stops: dict[tuple[float, float], dict[str, int]] = {}
    for bg in ("above", "previous"):
        for mr in regions:
            for cs in grid:
                rs = [iterative_threshold(hist=h, c_s=cs, background=bg, min_region=mr)
                      for h in hists]
                per[bg][(mr, cs)] = curves[rows_i, [r.threshold + 1 for r in rs]]
                if bg == "above":
                    stops[(mr, cs)] = {k: sum(r.stop == k for r in rs)
                                       for k in ("contrast", "size", "region", "max_iter")}
    print("\n### IT on DeepCrack train: mean defect-class F (exact), background 'above'; "
          "rows min_region, columns C_s\n")
    print("| min_region | " + " | ".join(f"{c:.3f}" for c in grid) + " |")
    print("|---" * (len(grid) + 1) + "|")
    for mr in regions:
        print(f"| {mr} | " + " | ".join(f"{per['above'][(mr, c)].mean():.3f}" for c in grid) + " |")
    for bg in ("above", "previous"):  # keys "min_region/C_s"
        out[f"it_grid_{bg}"] = {f"{mr}/{cs}": float(v.mean()) for (mr, cs), v in per[bg].items()}

    # the paper's bare stop rule (min_region = 0): smallest C_s within one SE of the best
    res: dict[str, object] = {}
    for bg in ("above", "previous"):
        bare = {k: v for k, v in per[bg].items() if k[0] == 0.0}
        b, within = _one_se(bare)
        gb, gwithin = _one_se(per[bg])
        res[bg] = {"bare_best": b, "bare_best_f": float(bare[b].mean()),
                   "bare_one_se": min(within, key=lambda k: k[1]),
                   "guarded_best": gb, "guarded_best_f": float(per[bg][gb].mean()),
                   # smallest guard (closest to the bare rule), then smallest C_s
                   "guarded_one_se": min(gwithin)}
        print(f"\n{bg}: bare rule best C_s={b[1]} (F={bare[b].mean():.4f}), one-SE C_s="
              f"{res[bg]['bare_one_se'][1]}; with guard best {gb} (F={per[bg][gb].mean():.4f}), "
              f"one-SE (smallest guard, then C_s) {res[bg]['guarded_one_se']} "
              f"(F={per[bg][res[bg]['guarded_one_se']].mean():.4f})")
    sel = res["above"]["guarded_one_se"]  # type: ignore[index]
    print(f"selected (min_region, C_s) = {sel}; stop reasons on DeepCrack: {stops[sel]}")
    print(f"module defaults: C_S_DEFAULT={C_S_DEFAULT}, MIN_REGION_DEFAULT={MIN_REGION_DEFAULT}, "
          f"C_S_UNGUARDED={C_S_UNGUARDED}")
    out["it_selection"] = {
        bg: {k: list(v) if isinstance(v, tuple) else v for k, v in r.items()}  # type: ignore[union-attr]
        for bg, r in res.items()
    }
    out["it_selected_stops"] = stops[sel]

    print("\n### IT+: area guard and shape limits on DeepCrack train (IT at its defaults)\n")
    print("| min_fraction | min_area | min_elongation | min_length | F |\n|---|---|---|---|---|")
    rows = []
    shapes = [(0, 0, 0), (20, 6, 30), (30, 8, 40), (60, 10, 60)]
    for mf in (0.0, 0.01, 0.015, 0.02, 0.025, 0.03, 0.04):
        ts = [threshold_it_plus(hist=h, min_fraction=mf) for h in hists]
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

    print("\n### IT+: guard gate, per-component contrast floor, elongation of long components "
          "(DeepCrack train; the rest at the defaults)\n")
    print("| guard_contrast | min_contrast | min_long_elongation | F |\n|---|---|---|---|")
    rows = []
    for gc in (0.0, 0.1):
        ts = [threshold_it_plus(hist=h, guard_contrast=gc) for h in hists]
        raws = [cv2.threshold(s.grey, t, 255, cv2.THRESH_BINARY_INV)[1] for s, t in zip(samples, ts)]
        for mc in (0.0, 0.06, 0.08, 0.1, 0.12):
            for mle in (0.0, 4.0, 5.0, 6.0):
                masks = [shape_filter(r, grey=s.grey, min_contrast=mc, min_long_elongation=mle)
                         for r, s in zip(raws, samples)]
                f = float(np.mean([f_measure(m, g)[0] for m, g in zip(masks, gts)]))
                rows.append({"guard_contrast": gc, "min_contrast": mc, "min_long_elongation": mle, "f": f})
                print(f"| {gc} | {mc} | {mle} | {f:.4f} |")
    top = max(rows, key=lambda r: r["f"])
    print(f"\nbest IT+ component setting: {top}")
    out["it_plus_component_grid"] = rows
    out["it_plus_component_best"] = top

    print("\n### IT+bh: black-hat size and kept share of its response (DeepCrack train)\n")
    print("| size | top_fraction | F |\n|---|---|---|")
    rows = []
    for size in (9, 15, 21, 31):
        for q in (0.03, 0.05, 0.08):
            f = float(np.mean([f_measure(it_plus_bh_mask(s.grey, size=size, top_fraction=q)[0], g)[0]
                               for s, g in zip(samples, gts)]))
            rows.append({"size": size, "top_fraction": q, "f": f})
            print(f"| {size} | {q} | {f:.4f} |")
    top = max(rows, key=lambda r: r["f"])
    print(f"\nbest IT+bh setting: {top}")
    out["it_plus_bh_grid"] = rows
    out["it_plus_bh_best"] = top
    return out


# ----------------------------------------------------------------------------------------- ridge
def ridge(data: Path) -> dict[str, object]:
    """IT+r's grid on the training splits: DeepCrack-train and CrackForest's odd-numbered half
    (001, 003, ...); the even half is printed apart as held out (nothing is chosen from it)."""
    dc = load_dataset(data / "deepcrack-train")
    cf = load_dataset(data / "crackforest")
    train, test = cf[::2], cf[1::2]
    base = dict(RIDGE_DEFAULTS)
    grid = [{}] + [{k: v} for k, vs in (("sigma", (2.0, 2.5)), ("edge_weight", (0.0, 1.0)), ("q_low", (0.03, 0.045)),
                                         ("rel_contrast", (0.4, 0.6)), ("fallback_contrast", (0.05, 0.1)))
                   for v in vs]

    def f(samples: list, kw: dict) -> float:
        return float(np.mean([f_measure(it_plus_ridge_mask(s.grey, **kw)[0], s.mask)[0] for s in samples]))

    print("\n### IT+r: one parameter at a time around the defaults (exact F; CrackForest train = odd-numbered "
          "half, test = even half, held out)\n")
    print("| change | DeepCrack-train | CrackForest train | CrackForest test |\n|---|---|---|---|")
    rows = []
    for ch in grid:
        kw = {**base, **ch}
        r = {"change": ch, "deepcrack_train": f(dc, kw), "crackforest_train": f(train, kw),
             "crackforest_test": f(test, kw)}
        rows.append(r)
        print(f"| {ch or 'defaults'} | {r['deepcrack_train']:.3f} | {r['crackforest_train']:.3f} | "
              f"{r['crackforest_test']:.3f} |")
    return {"defaults": base, "rows": rows}


# --------------------------------------------------------------------------------------- quality
def quality(data: Path) -> dict[str, object]:
    out: dict[str, object] = {}
    for name in SETS:
        folder = data / name
        if not folder.is_dir():
            print(f"\n(skipping {name}: {folder} not found)")
            continue
        samples = load_dataset(folder)
        # the learned method is scored on its held-out folds only (``learned``): it was trained on the rest
        ev = evaluate(samples, [m for m in METHODS if m != "learned"], dataset=name)
        print("\n" + markdown_table(ev))
        m = ev.mean
        goals = {
            "it_beats_otsu_ve_itth_sdd": all(m["it"]["f"] > m[k]["f"] for k in ("otsu", "ve", "itth", "sdd")),
            "it_plus_beats_it": m["it+"]["f"] > m["it"]["f"],
        }
        print(f"\ngoals on {name}: {goals}")
        out[name] = {"mean": m, "goals": goals, "per_image": ev.per_image, "images": ev.names,
                     "it_sensitivity": _it_sensitivity(samples)}
    _print_sensitivity(out)
    return out


def _it_sensitivity(samples: list) -> dict[str, dict[str, float]]:
    """Mean defect-class F of IT over C_s, bare rule and with the default size guard.

    A diagnostic of how far the defaults sit from each set's own optimum; no default is
    chosen from it (they come from ``tune`` on the DeepCrack training split only).
    """
    curves = _f_curves(samples)
    hists = [histogram(s.grey) for s in samples]
    i = np.arange(len(samples))
    out: dict[str, dict[str, float]] = {"bare": {}, "guarded": {}}
    for cs in SENS_GRID:
        for key, mr in (("bare", 0.0), ("guarded", MIN_REGION_DEFAULT)):
            ts = [iterative_threshold(hist=h, c_s=cs, min_region=mr).threshold + 1 for h in hists]
            out[key][f"{cs:.3f}"] = float(curves[i, ts].mean())
    return out


def _print_sensitivity(res: dict[str, object]) -> None:
    names = [n for n in SETS if n in res]
    if not names:
        return
    print("\n### IT sensitivity to C_s (mean defect-class F, exact; diagnostic only, no choice "
          f"is made here). bare = paper's stop rule only; guarded = min_region "
          f"{MIN_REGION_DEFAULT}\n")
    cols = [f"{n} {k}" for n in names for k in ("bare", "guarded")]
    print("| C_s | " + " | ".join(cols) + " |\n" + "|---" * (len(cols) + 1) + "|")
    for cs in SENS_GRID:
        vals = [res[n]["it_sensitivity"][k][f"{cs:.3f}"]  # type: ignore[index]
                for n in names for k in ("bare", "guarded")]
        print(f"| {cs:.3f} | " + " | ".join(f"{v:.3f}" for v in vals) + " |")


# ----------------------------------------------------------------------------------------- speed
def _frame(data: Path, size: tuple[int, int]) -> np.ndarray:
    src = data / "crackforest" / "images" / "001.jpg"
    img = cv2.imread(str(src), cv2.IMREAD_COLOR) if src.exists() else None
    if img is None:  # no data: a synthetic cracked surface
        from edge.world.surface import crack_image

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


def _it_plus_bh(bgr: np.ndarray) -> np.ndarray:
    return detect(bgr, "it+bh", with_defects=False).mask


def _it_plus_r(bgr: np.ndarray) -> np.ndarray:
    return detect(bgr, "it+r", with_defects=False).mask


def _it_plus_defects(bgr: np.ndarray) -> np.ndarray:
    return detect(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), "it+").mask


def speed(data: Path, repeats: int, threads: int) -> dict[str, object]:
    cv2.setNumThreads(threads)
    fns = {"otsu (cv2)": _otsu_cv2, "it": _it, "it+": _it_plus, "it+bh": _it_plus_bh, "it+r": _it_plus_r,
           "it+ with defect list": _it_plus_defects}
    out: dict[str, object] = {"cv2_threads": threads, "repeats": repeats,
                              "cpu": platform.processor() or platform.machine()}
    print(f"\n### Speed (OpenCV threads = {threads}; median over {repeats} interleaved blocks "
          "of >= 10 ms; BGR in, mask out)\n")
    print("| size | method | ms/frame (median) | fps | vs Otsu | CPU ms/frame | fps by CPU time |\n"
          "|---|---|---|---|---|---|---|")
    for w, h in ((480, 320), (4000, 3000)):
        bgr = _frame(data, (w, h))
        times: dict[str, list[float]] = {k: [] for k in fns}
        cpu: dict[str, list[float]] = {k: [] for k in fns}  # process CPU time: less hit by a loaded machine
        loops = {}
        for k, f in fns.items():  # warm-up, and calls per timed block (blocks of >= ~10 ms)
            t0 = time.perf_counter()
            f(bgr)
            loops[k] = max(1, int(0.01 / max(time.perf_counter() - t0, 1e-6)))
        for _ in range(repeats):  # interleaved blocks: every method sees the same machine load
            for k, f in fns.items():
                t0, c0 = time.perf_counter(), time.process_time()
                for _ in range(loops[k]):
                    f(bgr)
                times[k].append((time.perf_counter() - t0) * 1e3 / loops[k])
                cpu[k].append((time.process_time() - c0) * 1e3 / loops[k])
        med = {k: float(np.median(v)) for k, v in times.items()}
        key = f"{w}x{h}"
        cmed = {k: float(np.median(v)) for k, v in cpu.items()}
        out[key] = {k: {"ms_median": med[k], "ms_p90": float(np.percentile(times[k], 90)),
                        "fps": 1e3 / med[k], "ratio_to_otsu": med[k] / med["otsu (cv2)"],
                        "cpu_ms_median": cmed[k], "fps_cpu": 1e3 / max(cmed[k], 1e-6)}
                    for k in fns}
        for k in fns:
            print(f"| {key} | {k} | {med[k]:.2f} | {1e3 / med[k]:.0f} | {med[k] / med['otsu (cv2)']:.2f}x | "
                  f"{cmed[k]:.2f} | {1e3 / max(cmed[k], 1e-6):.0f} |")
    big = out["4000x3000"]
    out["goals"] = {
        "it_at_most_2x_otsu_480": out["480x320"]["it"]["ratio_to_otsu"] <= 2.0,  # type: ignore[index]
        "it_at_most_2x_otsu_12mp": big["it"]["ratio_to_otsu"] <= 2.0,  # type: ignore[index]
        "it_30fps_12mp": big["it"]["fps"] >= 30,  # type: ignore[index]
        "it_plus_20fps_12mp": big["it+"]["fps"] >= 20,  # type: ignore[index]
        "it_plus_bh_20fps_12mp": big["it+bh"]["fps"] >= 20,  # type: ignore[index]
        "it_plus_r_20fps_12mp": big["it+r"]["fps"] >= 20,  # type: ignore[index]
        "it_plus_r_20fps_12mp_cpu": big["it+r"]["fps_cpu"] >= 20,  # type: ignore[index]
    }
    print(f"\ngoals: {out['goals']}")
    return out


# --------------------------------------------------------------------------------------- learned
def learned(data: Path, repeats: int, threads: int, candidate: Path | None = None) -> dict[str, object]:
    """The learned method beside IT+r: exact and 2-px F, precision, recall on the shipped model's held-out
    folds (:func:`services.detector.learned.splits`: CrackForest's even-numbered half, every fifth
    DeepCrack-train image; never trained on nor used for model selection), and ms per frame (grey in, mask
    out, OpenCV limited to ``threads``) at 640x480 and on a 12 MP capture's 1/4 decode (1000x750, the
    detector's real-time input, services.detector.pipeline). A ``candidate`` model is timed beside them
    (cv2.dnn), never scored: the held-out folds judge only a model that ships."""
    import os

    from protocol.imagecodec import decode_image
    from services.detector.learned import RUNTIME_ENV, RUNTIMES, _has_openvino, learned_mask, runtime, splits

    cv2.setNumThreads(threads)
    methods = ["learned", "it+r"]
    out: dict[str, object] = {"methods": methods, "cv2_threads": threads, "repeats": repeats,
                              "runtime (quality)": runtime()}
    print(f"\nthe learned method's quality on runtime {runtime()} (services.detector.learned.runtime)")
    for name in SETS:
        folder = data / name
        if not folder.is_dir():
            print(f"\n(skipping {name}: {folder} not found)")
            continue
        samples = load_dataset(folder)
        held = set(splits([s.name for s in samples], name)["test"])
        ev = evaluate([s for s in samples if s.name in held], methods, dataset=f"{name} held-out fold")
        print("\n" + markdown_table(ev))
        out[name] = {"images": ev.names, "mean": ev.mean}
    frames = {"640x480": cv2.cvtColor(_frame(data, (640, 480)), cv2.COLOR_BGR2GRAY)}
    jpeg = cv2.imencode(".jpg", _frame(data, (4000, 3000)), [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
    frames["12 MP at 1/4 (1000x750)"] = decode_image(jpeg, grey=True, reduce=4)
    print(f"\n### Learned vs IT+r speed (OpenCV threads = {threads}; median of {repeats} interleaved runs; "
          "grey in, mask out)\n\n| frame | method | ms/frame (median) | p90 | CPU ms/frame |\n|---|---|---|---|---|")
    speed_rows: dict[str, object] = {}
    # the learned method on each runtime installed (services.detector.learned.runtime), beside IT+r
    timed = [(f"learned ({r})", "learned", r) for r in RUNTIMES if r == "opencv" or _has_openvino()]
    if candidate is not None:
        timed.append((f"candidate {candidate.name} (opencv)", "candidate", "opencv"))
    timed.append(("it+r", "it+r", None))
    env0 = os.environ.get(RUNTIME_ENV)

    def run(g: np.ndarray, m: str, rt: str | None) -> None:
        if rt is not None:
            os.environ[RUNTIME_ENV] = rt
        if m == "candidate":
            learned_mask(g, model=candidate)
        else:
            detect(g, m, with_defects=False)

    try:
        for key, grey in frames.items():
            times: dict[str, list[float]] = {k: [] for k, _, _ in timed}
            cpu: dict[str, list[float]] = {k: [] for k, _, _ in timed}
            for _, m, rt in timed:
                run(grey, m, rt)  # warm-up (the model loads once; OpenVINO builds this size's kernels)
            for _ in range(repeats):
                for k, m, rt in timed:
                    t0, c0 = time.perf_counter(), time.process_time()
                    run(grey, m, rt)
                    times[k].append((time.perf_counter() - t0) * 1e3)
                    cpu[k].append((time.process_time() - c0) * 1e3)
            speed_rows[key] = {k: {"ms_median": float(np.median(times[k])), "ms_p90": float(np.percentile(times[k], 90)),
                                   "cpu_ms_median": float(np.median(cpu[k]))} for k, _, _ in timed}
            for k, _, _ in timed:
                r = speed_rows[key][k]  # type: ignore[index]
                print(f"| {key} | {k} | {r['ms_median']:.1f} | {r['ms_p90']:.1f} | {r['cpu_ms_median']:.1f} |")
    finally:
        if env0 is None:
            os.environ.pop(RUNTIME_ENV, None)
        else:
            os.environ[RUNTIME_ENV] = env0
    out["speed"] = speed_rows
    return out


# ------------------------------------------------------------------------------------------ pool
def _timed_analyse(meta: object, jpeg: bytes, method: str) -> tuple[float, float, int]:
    """In a worker: :func:`services.detector.pipeline.analyse` of one frame; (wall ms, CPU ms, OpenCV threads)."""
    from services.detector.pipeline import analyse

    t0, c0 = time.perf_counter(), time.process_time()
    analyse(meta, jpeg, method)  # type: ignore[arg-type]
    return (time.perf_counter() - t0) * 1e3, (time.process_time() - c0) * 1e3, cv2.getNumThreads()


def pool(repeats: int, workers: int = 2) -> dict[str, object]:
    """The worker pool on the nominal mission's captures (monorail, 640x480), in bursts of three frames
    submitted together, per method and per OpenCV thread count in each worker (1, and OpenCV's default:
    one per core)."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    from edge.world.wall import synthetic_surface
    from protocol.scenario import load_scenario
    from services.detector.pool import DetectorPool
    from services.inspection.captures import synthetic_captures

    sc = load_scenario("monorail")
    caps = synthetic_captures(sc, synthetic_surface(sc), frame_size=(640, 480))
    bursts = [caps[i:i + 3] for i in range(0, len(caps), 3)][:max(1, repeats)]
    cores = os.cpu_count() or 1
    from services.detector.learned import runtime

    out: dict[str, object] = {"workers": workers, "bursts": len(bursts), "frames": sum(len(b) for b in bursts),
                              "learned runtime": runtime()}
    print(f"\n### The worker pool ({workers} workers; the nominal mission's {out['frames']} captures, 640x480, in "
          f"bursts of three; learned on {out['learned runtime']})\n\n| method | OpenCV threads per worker | latency p50 / p95 / max (ms) | worker CPU ms "
          "per frame (median) |\n|---|---|---|---|")
    for method in ("learned", "it+r"):
        for threads in (1, cores):
            p = DetectorPool(workers, threads=threads)
            try:
                p.warm(method=method)
                lat: list[float] = []
                cpu: list[float] = []
                seen: set[int] = set()

                def one(c: object) -> None:
                    t0 = time.perf_counter()
                    _, c_ms, n = p.call(_timed_analyse, c.meta, c.jpeg, method)  # type: ignore[attr-defined]
                    lat.append((time.perf_counter() - t0) * 1e3)
                    cpu.append(c_ms)
                    seen.add(n)

                with ThreadPoolExecutor(3) as ex:
                    for b in bursts:
                        list(ex.map(one, b))
            finally:
                p.close()
            row = {"latency_ms": {"p50": float(np.median(lat)), "p95": float(np.percentile(lat, 95)),
                                  "max": float(max(lat))},
                   "worker_cpu_ms_median": float(np.median(cpu)), "threads_seen": sorted(seen)}
            out[f"{method}, {threads} threads"] = row
            la = row["latency_ms"]
            print(f"| {method} | {threads} | {la['p50']:.0f} / {la['p95']:.0f} / {la['max']:.0f} | "
                  f"{row['worker_cpu_ms_median']:.0f} |", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder holding the data sets")
    ap.add_argument("--only", nargs="+", choices=("tune", "ridge", "quality", "speed", "learned", "pool"),
                    default=["tune", "ridge", "quality", "speed", "learned"])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--threads", type=int, default=1, help="cv2.setNumThreads for the speed runs")
    ap.add_argument("--candidate", type=Path, help="with --only learned: also time this ONNX model (not scored)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "detect.json")
    a = ap.parse_args(argv)
    has_data = all((a.data / s).is_dir() for s in SETS)
    res: dict[str, object] = {}
    if {"tune", "ridge", "quality"} & set(a.only):
        if not has_data:
            print(f"data sets not found under {a.data}: skipping tune and quality")
        else:
            if "tune" in a.only:
                res["tune"] = tune(a.data)
            if "ridge" in a.only:
                res["ridge"] = ridge(a.data)
            if "quality" in a.only:
                res["quality"] = quality(a.data)
    if "speed" in a.only:
        res["speed"] = speed(a.data, a.repeats, a.threads)
    if "learned" in a.only:
        res["learned"] = learned(a.data, a.repeats, a.threads, a.candidate)
    if "pool" in a.only:
        res["pool"] = pool(a.repeats)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1))
    print(f"\nwrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
