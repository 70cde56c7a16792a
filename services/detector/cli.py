"""``skynet detect``: detect defects in an image, evaluate methods on a data set, or benchmark.

Usage::

    skynet detect IMAGE [--method M] [--out DIR]
    skynet detect eval --dataset DIR [--methods M ...] [--out DIR] [--sheet PNG] [--limit N]
    skynet detect bench [bench/detect.py options]
"""

from __future__ import annotations

import argparse
import runpy
import sys
from pathlib import Path

import cv2

from .detect import METHODS, detect

__all__ = ["main"]


def _eval(argv: list[str]) -> int:
    from .evaluate import contact_sheet, evaluate, load_dataset, markdown_table, write_results

    ap = argparse.ArgumentParser(prog="skynet detect eval", description="score methods on a data set")
    ap.add_argument("--dataset", required=True, help="folder with images/ and masks/")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--out", help="write eval.md and eval.json here")
    ap.add_argument("--sheet", help="write a contact sheet PNG here")
    ap.add_argument("--limit", type=int, help="only the first N images")
    a = ap.parse_args(argv)
    try:
        samples = load_dataset(a.dataset, a.limit)
    except ValueError as e:
        print(f"skynet detect eval: {e}", file=sys.stderr)
        return 2
    ev = evaluate(samples, a.methods, dataset=Path(a.dataset).name)
    print(markdown_table(ev))
    if a.out:
        md, js = write_results(ev, a.out)
        print(f"\nwrote {md} and {js}")
    if a.sheet:
        print(f"wrote {contact_sheet(samples, a.methods, a.sheet)}")
    return 0


def _bench(argv: list[str]) -> int:
    script = Path(__file__).resolve().parents[2] / "bench" / "detect.py"
    if not script.exists():
        print(f"skynet detect bench: {script} not found", file=sys.stderr)
        return 2
    old = sys.argv
    try:
        sys.argv = [str(script), *argv]
        runpy.run_path(str(script), run_name="__main__")
    except SystemExit as e:
        return int(e.code or 0)
    finally:
        sys.argv = old
    return 0


def _image(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="skynet detect", description="detect dark defects in one image")
    ap.add_argument("image")
    ap.add_argument("--method", default="it+", choices=list(METHODS))
    ap.add_argument("--out", default=".", help="folder for <name>_mask.png and <name>_overlay.png")
    a = ap.parse_args(argv)
    bgr = cv2.imread(a.image, cv2.IMREAD_COLOR)
    if bgr is None:
        print(f"skynet detect: cannot read {a.image}", file=sys.stderr)
        return 2
    det = detect(bgr, a.method)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = Path(a.image).stem
    overlay = bgr.copy()
    overlay[det.mask > 0] = (0, 0, 255)
    overlay = cv2.addWeighted(bgr, 0.4, overlay, 0.6, 0)
    for d in det.defects[:200]:
        x, y, w, h = d.bbox
        cv2.rectangle(overlay, (x, y), (x + w - 1, y + h - 1), (0, 255, 255), 1)
    cv2.imwrite(str(out / f"{stem}_mask.png"), det.mask)
    cv2.imwrite(str(out / f"{stem}_overlay.png"), overlay)
    print(f"{a.image}: method {a.method}, threshold {det.threshold}, "
          f"{len(det.defects)} defects, {100 * det.defect_fraction:.2f} % of pixels")
    for d in det.defects[:10]:
        print(f"  area {d.area_px:7d} px  bbox {d.bbox}  centroid ({d.centroid[0]:.1f}, "
              f"{d.centroid[1]:.1f})  contrast {d.contrast:.3f}")
    print(f"wrote {out / (stem + '_mask.png')} and {out / (stem + '_overlay.png')}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in {"-h", "--help"}:
        print(__doc__)
        return 0
    if args[0] == "eval":
        return _eval(args[1:])
    if args[0] == "bench":
        return _bench(args[1:])
    return _image(args)


if __name__ == "__main__":
    raise SystemExit(main())
