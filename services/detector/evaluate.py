"""Evaluate detection methods on a folder of images with pixel ground truth (Table II style).

Design notes: docs/detector.md (services/detector/evaluate.py).
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .detect import METHODS
from .metrics import score

__all__ = ["Sample", "load_dataset", "evaluate", "markdown_table", "contact_sheet", "write_results"]

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff"}
SCORE_KEYS = ("f", "f_tol", "f_mean2", "precision", "recall", "ms")


@dataclass(frozen=True)
class Sample:
    name: str
    grey: np.ndarray
    mask: np.ndarray


def load_dataset(folder: str | Path, limit: int | None = None) -> list[Sample]:
    """Read ``folder/images/*`` as grey and ``folder/masks/<base>.png`` (255 = defect).

    Raises ``ValueError`` when the folder layout is wrong, a mask is missing or shapes differ.
    """
    root = Path(folder)
    img_dir, mask_dir = root / "images", root / "masks"
    if not img_dir.is_dir() or not mask_dir.is_dir():
        raise ValueError(f"{root} must contain images/ and masks/")
    files = sorted(p for p in img_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if limit is not None:
        files = files[:limit]
    if not files:
        raise ValueError(f"no images in {img_dir}")
    out = []
    for p in files:
        mp = mask_dir / f"{p.stem}.png"
        if not mp.exists():
            raise ValueError(f"missing mask {mp}")
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        m = cv2.imread(str(mp), cv2.IMREAD_GRAYSCALE)
        if g is None or m is None:
            raise ValueError(f"cannot read {p} or {mp}")
        if g.shape != m.shape:
            raise ValueError(f"{p.name}: image {g.shape} and mask {m.shape} differ")
        out.append(Sample(p.stem, g, np.where(m > 127, 255, 0).astype(np.uint8)))
    return out


@dataclass
class Evaluation:
    """Per-image and mean scores: ``per_image[method][i]`` and ``mean[method]`` dicts."""

    dataset: str
    names: list[str]
    per_image: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    mean: dict[str, dict[str, float]] = field(default_factory=dict)

    def as_dict(self) -> dict[str, object]:
        return {"dataset": self.dataset, "images": self.names, "mean": self.mean,
                "per_image": self.per_image}


def evaluate(
    samples: Sequence[Sample],
    methods: Sequence[str] = tuple(METHODS),
    dataset: str = "",
    params: dict[str, dict[str, object]] | None = None,
    tol: float = 2.0,
) -> Evaluation:
    """Score every method on every sample; ``params[method]`` are extra method parameters."""
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise ValueError(f"unknown methods {bad}; choose from {sorted(METHODS)}")
    if not samples:
        raise ValueError("no samples")
    params = params or {}
    ev = Evaluation(dataset=dataset, names=[s.name for s in samples])
    for m in methods:
        fn, kw = METHODS[m], params.get(m, {})
        rows = []
        for s in samples:
            t0 = time.perf_counter()
            pred, _ = fn(s.grey, **kw)
            ms = (time.perf_counter() - t0) * 1e3
            sc = score(pred, s.mask, tol)
            rows.append({"f": sc.f, "f_tol": sc.f_tol, "f_mean2": sc.f_mean2,
                         "precision": sc.precision, "recall": sc.recall, "ms": ms})
        ev.per_image[m] = rows
        ev.mean[m] = {k: float(np.mean([r[k] for r in rows])) for k in SCORE_KEYS}
    return ev


def markdown_table(ev: Evaluation, per_image: bool = False) -> str:
    """Table II-style Markdown: mean scores per method (and optionally defect F per image)."""
    head = ("| method | F defect (exact) | F defect (2 px) | F two-class mean | precision | "
            "recall | ms/image |\n|---|---|---|---|---|---|---|")
    lines = [f"**{ev.dataset}** ({len(ev.names)} images, means over images)", "", head]
    for m, r in ev.mean.items():
        lines.append(f"| {m} | {r['f']:.4f} | {r['f_tol']:.4f} | {r['f_mean2']:.4f} | "
                     f"{r['precision']:.4f} | {r['recall']:.4f} | {r['ms']:.2f} |")
    if per_image:
        ms = list(ev.per_image)
        lines += ["", "Defect-class F (exact) per image:", "",
                  "| image | " + " | ".join(ms) + " |", "|---" * (len(ms) + 1) + "|"]
        for i, name in enumerate(ev.names):
            lines.append(f"| {name} | " + " | ".join(f"{ev.per_image[m][i]['f']:.4f}" for m in ms) + " |")
    return "\n".join(lines)


def contact_sheet(
    samples: Sequence[Sample], methods: Sequence[str], path: str | Path, rows: int = 6,
    thumb_w: int = 240,
) -> Path:
    """PNG grid: one row per image (first ``rows``), columns original, ground truth, methods."""
    if not samples:
        raise ValueError("no samples")
    cols = ["image", "truth", *methods]
    tiles = []
    for s in samples[:rows]:
        h = max(1, round(s.grey.shape[0] * thumb_w / s.grey.shape[1]))
        row = [s.grey, s.mask] + [METHODS[m](s.grey)[0] for m in methods]
        tiles.append(np.hstack([cv2.resize(t, (thumb_w, h), interpolation=cv2.INTER_AREA) for t in row]))
    width = max(t.shape[1] for t in tiles)
    header = np.full((22, width), 255, np.uint8)
    for j, c in enumerate(cols):
        cv2.putText(header, c, (j * thumb_w + 4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 0, 1, cv2.LINE_AA)
    sheet = np.vstack([header] + [np.pad(t, ((0, 2), (0, width - t.shape[1])), constant_values=255) for t in tiles])
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), sheet):
        raise ValueError(f"cannot write {out}")
    return out


def write_results(ev: Evaluation, out_dir: str | Path, stem: str = "eval") -> tuple[Path, Path]:
    """Write ``<stem>.md`` (table) and ``<stem>.json`` (all numbers) into ``out_dir``."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    md, js = d / f"{stem}.md", d / f"{stem}.json"
    md.write_text(markdown_table(ev, per_image=True) + "\n")
    js.write_text(json.dumps(ev.as_dict(), indent=1))
    return md, js
