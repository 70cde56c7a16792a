"""Evaluation over a data set folder and the ``skynet detect`` command line."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from services.detector.cli import main
from services.detector.evaluate import evaluate, load_dataset, markdown_table

REAL = Path("/work/shared/data/deepcrack-train")


def make_dataset(root: Path, n: int = 3) -> Path:
    (root / "images").mkdir(parents=True)
    (root / "masks").mkdir()
    rng = np.random.default_rng(0)
    for i in range(n):
        g = np.clip(rng.normal(170, 8, (64, 96)), 0, 255).astype(np.uint8)
        gt = np.zeros_like(g)
        cv2.line(gt, (5, 10 + 10 * i), (90, 40 + 5 * i), 255, 2)
        g[gt > 0] = 60
        cv2.imwrite(str(root / "images" / f"{i:03d}.png"), cv2.cvtColor(g, cv2.COLOR_GRAY2BGR))
        cv2.imwrite(str(root / "masks" / f"{i:03d}.png"), gt)
    return root


def test_evaluate_scores_every_method(tmp_path):
    samples = load_dataset(make_dataset(tmp_path / "ds"))
    assert [s.name for s in samples] == ["000", "001", "002"]
    ev = evaluate(samples, ["otsu", "it", "it+"], dataset="toy")
    for m in ("otsu", "it", "it+"):
        assert len(ev.per_image[m]) == 3
        assert set(ev.mean[m]) == {"f", "f_tol", "f_mean2", "precision", "recall", "ms"}
    assert ev.mean["it"]["f"] > 0.9  # the drawn lines are 110 levels darker: easy
    assert ev.mean["it"]["f_tol"] >= ev.mean["it"]["f"]
    table = markdown_table(ev, per_image=True)
    assert "| it+ |" in table and "| 001 |" in table
    with pytest.raises(ValueError):
        evaluate(samples, ["nope"])


def test_load_dataset_errors(tmp_path):
    with pytest.raises(ValueError):
        load_dataset(tmp_path)
    root = make_dataset(tmp_path / "ds", n=1)
    (root / "masks" / "000.png").unlink()
    with pytest.raises(ValueError, match="missing mask"):
        load_dataset(root)


def test_cli_eval_writes_table_json_and_sheet(tmp_path, capsys):
    root = make_dataset(tmp_path / "ds")
    out, sheet = tmp_path / "out", tmp_path / "sheet.png"
    rc = main(["eval", "--dataset", str(root), "--methods", "otsu", "it", "it+",
               "--out", str(out), "--sheet", str(sheet)])
    assert rc == 0
    assert "F defect (2 px)" in capsys.readouterr().out
    data = json.loads((out / "eval.json").read_text())
    assert set(data["mean"]) == {"otsu", "it", "it+"} and data["images"] == ["000", "001", "002"]
    img = cv2.imread(str(sheet), cv2.IMREAD_GRAYSCALE)
    assert img is not None and img.shape[1] == 5 * 240  # image, truth, 3 methods
    assert main(["eval", "--dataset", str(tmp_path / "nowhere")]) == 2


def test_cli_single_image(tmp_path, capsys):
    root = make_dataset(tmp_path / "ds", n=1)
    rc = main(["image", str(root / "images" / "000.png"), "--method", "it", "--out", str(tmp_path / "o")])
    assert rc == 0
    mask = cv2.imread(str(tmp_path / "o" / "000_mask.png"), cv2.IMREAD_GRAYSCALE)
    gt = cv2.imread(str(root / "masks" / "000.png"), cv2.IMREAD_GRAYSCALE)
    assert mask is not None and (mask[gt > 0] == 255).all()
    assert (tmp_path / "o" / "000_overlay.png").exists()
    assert main(["image", str(tmp_path / "missing.png")]) == 2


@pytest.mark.data
@pytest.mark.skipif(not REAL.is_dir(), reason="DeepCrack training split not at /work/shared/data")
def test_real_images_it_and_it_plus_beat_otsu():
    samples = load_dataset(REAL, limit=12)
    ev = evaluate(samples, ["otsu", "it", "it+"], dataset="deepcrack-train")
    assert ev.mean["it"]["f"] > ev.mean["otsu"]["f"]
    assert ev.mean["it+"]["f"] > ev.mean["it"]["f"]
