"""``skynet detect``: detect defects in an image, or evaluate methods on a data set.

Its options: docs/cli.md. The detector's benchmark is a script of its own: ``python bench/detect.py``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2

from protocol.cliconfig import show_defaults
from protocol.textsafe import printable

from .detect import METHODS, detect
from .exposure import exposure_problem

__all__ = ["main", "DEFAULT_METHOD"]

#: the method ``skynet detect image`` uses unless told: the detector service's (``skynet detector --method``),
#: so an image checked by hand is judged as in a mission
DEFAULT_METHOD = "it+r"


def build_parser() -> argparse.ArgumentParser:
    """``skynet detect image|eval``, one subparser each."""
    parser = argparse.ArgumentParser(prog="skynet detect", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True, metavar="image|eval")
    ap = commands.add_parser("image", help="detect dark defects in one image")
    ap.add_argument("image")
    ap.add_argument("--method", default=DEFAULT_METHOD, choices=list(METHODS),
                    help="detection method (default: %(default)s, the detector service's)")
    ap.add_argument("--out", default=".", help="folder for <name>_mask.png and <name>_overlay.png")
    ap = commands.add_parser("eval", help="score methods on a data set (Table II)")
    ap.add_argument("--dataset", required=True, help="folder with images/ and masks/")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--out", help="write eval.md and eval.json here")
    ap.add_argument("--sheet", help="write a contact sheet PNG here")
    ap.add_argument("--limit", type=int, help="only the first N images")
    return show_defaults(parser)


def _eval(a: argparse.Namespace) -> int:
    from .evaluate import contact_sheet, evaluate, load_dataset, markdown_table, write_results

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


def _image(a: argparse.Namespace) -> int:
    bgr = cv2.imread(a.image, cv2.IMREAD_COLOR)
    if bgr is None:
        print(f"skynet detect: cannot read {a.image}", file=sys.stderr)
        return 2
    problem = exposure_problem(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    if problem is not None:  # as the detector service reports such a frame: failed, saying why
        print(f"skynet detect: {printable(a.image)} shows no surface ({problem}): not analysed", file=sys.stderr)
        return 1
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
    a = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    if "learned" in ([a.method] if a.command == "image" else a.methods):
        from .learned import ModelError, warm_up

        try:  # a bad model file or runtime: one line naming it
            warm_up(shapes=((16, 24),))
        except ModelError as exc:
            print(f"skynet detect: {exc}", file=sys.stderr)
            return 2
    return {"image": _image, "eval": _eval}[a.command](a)


if __name__ == "__main__":
    raise SystemExit(main())
