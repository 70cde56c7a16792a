"""What a newcomer sees first: the same defaults everywhere they mean the same thing, and help that shows them."""

from __future__ import annotations

import subprocess
import sys
import tomllib

from tests.conftest import ROOT


def test_detect_image_uses_the_detector_services_method_by_default():
    from services.detector.cli import build_parser as detect_parser
    from services.detector.service import build_parser as service_parser

    image = detect_parser().parse_args(["image", "x.png"])
    assert image.method == service_parser().parse_args([]).method


def test_video_help_shows_its_defaults():
    out = subprocess.run([sys.executable, "-m", "services.cli", "video", "--help"], capture_output=True, text=True,
                         cwd=ROOT, timeout=60).stdout
    flat = " ".join(out.split())
    for option, default in [("--preview-port", "5600"), ("--codec", "h264"), ("--sdp-dir", "sdp"), ("--rtp-host", "127.0.0.1"),
                            ("--capture-port", "5700")]:
        assert option in flat and f"(default: {default})" in flat, (option, out)


def test_the_license_is_an_spdx_expression_and_the_backend_supports_it():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert meta["project"]["license"] == "Apache-2.0"  # PEP 639: a string, not the deprecated table
    # setuptools reads PEP 639 license expressions from 77.0 on
    assert any(r.replace(" ", "").startswith("setuptools>=") and
               tuple(int(x) for x in r.split(">=")[1].split(".")[:1]) >= (77,)
               for r in meta["build-system"]["requires"])
