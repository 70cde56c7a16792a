"""services.detector.cli: `skynet detect image` on a frame that shows no surface says so in one line, as the
detector service reports such a frame, instead of '0 defects'."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from edge.world.surface import textured_background

ROOT = Path(__file__).resolve().parents[3]


def _detect_image(img: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "services.cli", "detect", "image", str(img), "--out", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_an_image_that_shows_no_surface_is_not_analysed(tmp_path):
    img = tmp_path / "lens\x1b[2Jcap.png"
    cv2.imwrite(str(img), np.zeros((120, 160), np.uint8))
    r = _detect_image(img, tmp_path / "out")
    assert r.returncode == 1 and r.stdout == "", r.stdout + r.stderr
    assert r.stderr.strip().splitlines() == [
        f"skynet detect: {tmp_path}/lens\\x1b[2Jcap.png shows no surface (under-exposed, 100% of the frame black): "
        "not analysed"]
    assert not (tmp_path / "out").exists()


def test_a_wall_is_analysed(tmp_path):
    img = tmp_path / "wall.png"
    g = textured_background((120, 160), np.random.default_rng(4), roughness=6.0)
    cv2.line(g, (10, 20), (150, 100), 30, 2)
    cv2.imwrite(str(img), g)
    r = _detect_image(img, tmp_path / "out")
    assert r.returncode == 0 and "defects" in r.stdout and (tmp_path / "out" / "wall_mask.png").exists(), r.stderr
