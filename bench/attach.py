"""Attaching the tools to a running secure network: how long until they are up, and how long a refusal takes.

``skynet up --uavs 1`` runs in a temporary folder (its own development key set, mutual TLS); then, ``--runs``
times each, from the command's start: ``skynet web`` and ``skynet video`` with no options until their ready
line (the description file read, TLS session open with the tool's identity), and the one-line refusals of a
tool started where no network runs and of a tool given another CA's key set. Last, a ``skynet up`` whose
video cannot start (its SDP folder is a file): seconds from start until the launcher says so.

    .venv/bin/python bench/attach.py [--runs 3] [--out bench/results/attach.json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.orchestration.process import free_port  # noqa: E402

ENV = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}


def start(cwd: Path, *argv: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "services.cli", *argv], cwd=cwd, env=ENV, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def until(proc: subprocess.Popen, text: str, timeout: float = 120.0) -> float | None:
    """Seconds until a line with ``text`` (None: the process ended or the time ran out first)."""
    t0 = time.monotonic()
    for line in proc.stdout:
        if text in line:
            return time.monotonic() - t0
        if time.monotonic() - t0 > timeout:
            break
    return None


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def timed(cwd: Path, *argv: str) -> tuple[float, int, str]:
    t0 = time.monotonic()
    p = subprocess.run([sys.executable, "-m", "services.cli", *argv], cwd=cwd, env=ENV, capture_output=True,
                       text=True, timeout=180)
    return time.monotonic() - t0, p.returncode, p.stderr.strip().splitlines()[-1] if p.stderr.strip() else ""


def summary(xs: list[float]) -> dict:
    return {"runs": len(xs), "median_s": round(statistics.median(xs), 2), "max_s": round(max(xs), 2)} if xs else {}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "attach.json"))
    a = ap.parse_args()
    out: dict = {"runs": a.runs}
    with tempfile.TemporaryDirectory(prefix="skynet-attach-") as tmp:
        cwd = Path(tmp)
        up = start(cwd, "up", "--uavs", "1")
        try:
            ready = until(up, "network described in")
            if ready is None:
                print("skynet up did not come up", file=sys.stderr)
                return 1
            out["up_s"] = round(ready, 2)
            for tool, argv in (("web", ["web", "--web", f":{free_port()}"]),
                               ("video", ["video", "--preview-port", str(free_port() & ~1), "--sdp-dir", "sdp"])):
                times = []
                for _ in range(a.runs):
                    p = start(cwd, *argv)
                    t = until(p, f"{tool} up")
                    stop(p)
                    if t is not None:
                        times.append(t)
                out[f"{tool}_attach"] = summary(times)
            elsewhere = cwd / "elsewhere"
            elsewhere.mkdir()
            runs = [timed(elsewhere, "web", "--web", f":{free_port()}") for _ in range(a.runs)]
            out["refused_no_network"] = {**summary([t for t, _, _ in runs]), "line": runs[-1][2]}
            assert subprocess.run([sys.executable, "-m", "services.cli", "keys", "init", str(cwd / "other"), "--uavs",
                                   "1"], env=ENV, capture_output=True).returncode == 0
            runs = [timed(cwd, "video", "--keys", str(cwd / "other")) for _ in range(a.runs)]
            out["refused_other_ca"] = {**summary([t for t, _, _ in runs]), "line": runs[-1][2]}
        finally:
            stop(up)
        (cwd / "sdp-file").write_text("not a folder\n")
        up = start(cwd, "up", "--uavs", "1", "--video", "h264", "--sdp-dir", "sdp-file", "--preview-port",
                   str(free_port() & ~1))
        try:
            t = until(up, "video did not start", 180)
            out["start_failure_said_s"] = None if t is None else round(t, 2)
        finally:
            stop(up)
    print(json.dumps(out, indent=1))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
