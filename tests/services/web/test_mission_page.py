"""The live page as the operator composes it: ``skynet mission --web`` in the default secure mode, then the
recording replayed (``skynet replay``) and watched with ``skynet web``.

The mission prints the page's URL with its token; without it the page answers 403. Read through the
printed URL while the mission flies, the page's timeline has the mission's phases (the ground
station's and the UAVs' mode changes), captures and defect reports; its defect count is the report's (a crack seen by overlapping frames counted once) and is
below the per-frame detections. The replay of the mission's MCAP is labelled a replay (in headless
Chromium when it is installed) and its timeline has the UAVs' mode changes, captures and defect reports.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from protocol import keys
from services.orchestration.process import free_port
from tests.conftest import wait_until
from tests.readiness import launched

ROOT = Path(__file__).resolve().parents[3]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")


def get(url: str, token: str | None = None) -> tuple[int, bytes]:
    req = urllib.request.Request(url, headers={"Authorization": f"token {token}"} if token else {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()
    except (urllib.error.URLError, OSError):  # the page is gone (the mission ended) or not up yet
        return 0, b""


def lines_of(proc: subprocess.Popen, into: list[str]) -> threading.Thread:
    def run() -> None:
        for line in proc.stdout:
            into.append(line.rstrip("\n"))

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def printed_url(lines: list[str]) -> str | None:
    return next((m.group(1) for line in list(lines) if (m := re.search(r"web page at (\S+)", line))), None)


@pytest.mark.mission
def test_mission_page_timeline_defect_count_and_its_replay(group, gateway, tmp_path) -> None:
    out, port = tmp_path / "report", free_port()
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "mission", "--quiet", "--speed", "8", "--out",
                             str(out), "--web", f"127.0.0.1:{port}"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = lines_of(proc, lines)
    snaps: list[dict] = []
    try:
        assert wait_until(lambda: printed_url(lines) is not None or proc.poll() is not None, 120), lines[-20:]
        url = printed_url(lines)
        assert url and re.fullmatch(rf"http://127\.0\.0\.1:{port}/\?token=[A-Za-z0-9_-]{{16,}}", url), lines[-20:]
        token = url.split("token=", 1)[1]
        assert get(f"http://127.0.0.1:{port}/snapshot.json")[0] == 403  # no token, nothing
        while proc.poll() is None:  # the page, read as the mission flies
            code, body = get(f"http://127.0.0.1:{port}/snapshot.json", token)
            if code == 200:
                snaps.append(json.loads(body))
            time.sleep(0.5)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
        reader.join(10)
    assert proc.returncode == 0, "\n".join(lines[-40:])
    assert "INSECURE" not in "\n".join(lines)  # the default secure mode
    assert snaps, "\n".join(lines[-40:])
    last = snaps[-1]
    kinds = {e["kind"] for s in snaps for e in s["events"]}
    phases = {e["text"] for s in snaps for e in s["events"] if e["kind"] == "phase"}
    assert {"phase", "mode", "capture", "defect-report"} <= kinds, kinds
    assert {"discovery", "planning", "takeoff", "mission"} <= phases, phases
    assert all(s["source"] in ("live", None) for s in snaps)
    # the defect count: the report's way (the page's last count of all captures equals report.md's), below
    # the per-frame detections
    doc = json.loads((out / "inspection" / "defects.json").read_text())
    counted = [s["inspection"] for s in snaps if s["inspection"]]
    assert counted, "the page never counted the captures"
    # counted again when the last reports are in (phase "reports", "done"), while the report is being written
    assert counted[-1]["frames"] == doc["frames"] and counted[-1]["defects"] == len(doc["defects"]), \
        (counted[-3:], doc["frames"], len(doc["defects"]))
    assert f"{len(doc['defects'])} defects (" in (out / "report.md").read_text()
    assert last["detections"] > counted[-1]["defects"] > 0

    # the recording replayed and watched: labelled a replay, not live
    fleet, wport = keys.replay_fleet("watch"), free_port()  # the replay mark counts on a replay fleet only
    web = group.start("web", ["web", "--fleet", fleet, "--multilink", "--web", f"127.0.0.1:{wport}",
                              *[a for e in gateway for a in ("--connect", e)]])
    assert web.wait_ready(30), "\n".join(web.lines)
    wurl = printed_url(web.lines)
    replay = group.start("replay", ["replay", str(out / "mission.mcap"), "--speed", "2", "--as-fleet", fleet,
                                    "--multilink", *[a for e in gateway for a in ("--connect", e)]])
    wtoken = wurl.split("token=", 1)[1]

    def source() -> str | None:
        code, body = get(f"http://127.0.0.1:{wport}/snapshot.json", wtoken)
        return json.loads(body)["source"] if code == 200 else None

    assert wait_until(lambda: source() == "replay", 60), "\n".join(replay.lines[-20:] + web.lines[-20:])
    if CHROMIUM and DRIVER:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support.ui import WebDriverWait

        opts = Options()
        opts.binary_location = CHROMIUM
        for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
            opts.add_argument(a)
        driver = webdriver.Chrome(service=Service(executable_path=DRIVER), options=opts)
        try:
            driver.get(wurl)
            WebDriverWait(driver, 30).until(lambda d: d.find_element(By.ID, "conn").text == "replay")
            assert driver.execute_script("return document.querySelectorAll('#uavs tbody tr').length") >= 1
        finally:
            driver.quit()

    def replayed_kinds() -> set[str]:
        code, body = get(f"http://127.0.0.1:{wport}/snapshot.json", wtoken)
        return {e["kind"] for e in json.loads(body)["events"]} if code == 200 else set()

    # the replay's timeline: the UAVs' phases (mode changes), captures and defect reports, from the recording
    assert wait_until(lambda: {"mode", "capture", "defect-report"} <= replayed_kinds(), 90), replayed_kinds()


def test_up_prints_the_page_url_with_its_token_and_the_page_serves_the_fleet() -> None:
    """``skynet up --web``: the launcher prints the page's URL with the token it handed the page's process;
    that URL serves the live fleet, nothing is served without it; in the default secure mode (the page's own
    identity in the key set)."""
    port = free_port()
    with launched(["up", "--speed", "4", "--web", f"127.0.0.1:{port}"], cwd=ROOT, timeout=90) as up:
        lines = up.lines
        assert wait_until(lambda: printed_url(lines) is not None, 30), lines[-20:]
        url = printed_url(lines)
        assert url and re.fullmatch(rf"http://127\.0\.0\.1:{port}/\?token=[A-Za-z0-9_-]{{16,}}", url), lines[-20:]
        token = url.split("token=", 1)[1]

        def uavs() -> set[str]:
            code, body = get(f"http://127.0.0.1:{port}/snapshot.json", token)
            return set(json.loads(body)["uavs"]) if code == 200 else set()

        assert wait_until(lambda: {"1", "2", "3"} <= uavs(), 90), lines[-30:]
        assert get(f"http://127.0.0.1:{port}/snapshot.json")[0] == 403
        assert get(f"http://127.0.0.1:{port}/snapshot.json", "x" * 32)[0] == 403
