"""The live web page in a real headless browser (Debian's chromium through selenium + chromium-driver).

A ``skynet web`` process follows the bus; this test puts three moving UAVs, their live previews,
an event and a defect report on the bus, and a headless chromium loads the page: the UAVs' positions
change between two readings, a preview image is decoded, the defect count shows; a screenshot is
saved to ``tests/artifacts/web-page.png`` (git-ignored).
"""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.imagery import pack_image
from protocol.links import COMMAND, IMAGERY, TELEMETRY
from protocol.messages import Defect, DefectReport, Event, ImageMeta, Intrinsics, Mode, VehicleState
from protocol.rtp import RtpSender, ssrc_for
from services.orchestration.process import free_port

FLEET = "test"
ARTIFACTS = Path(__file__).resolve().parents[2] / "artifacts"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium drives the browser")
pytestmark = pytest.mark.skipif(not (CHROMIUM and DRIVER),
                                reason="needs Debian's chromium and chromium-driver (.ci/run installs them)")


def feed(bus: Bus, stop: threading.Event) -> None:
    states = {u: bus.publisher(keys.state(FLEET, u), TELEMETRY) for u in (1, 2, 3)}
    previews = {u: bus.publisher(keys.preview(FLEET, u), IMAGERY) for u in (1, 2, 3)}
    senders = {u: RtpSender(ssrc_for(u, 1)) for u in (1, 2, 3)}
    bus.publisher(keys.gcs_event(FLEET), COMMAND).put(Event(source="gcs", stamp=time.time(), kind="phase",
                                                           text="mission"))
    img = np.zeros((240, 320, 3), np.uint8)
    img[60:180, 80:240] = (30, 160, 220)
    jpeg = cv2.imencode(".jpg", img)[1].tobytes()
    k = 0
    while not stop.wait(0.05):
        now = time.time()
        for u in (1, 2, 3):
            pos = (55.0 - u, 35.0 + 0.2 * k, 25.0 + u)
            states[u].put(VehicleState(uav=u, seq=k, t=k * 0.05, stamp=now, pos=pos, vel=(0, 4, 0), att=(0, 0, 0),
                                       rates=(0, 0, 0), mode=Mode.MISSION, battery=0.9, ref=pos, tau=k * 0.05))
            if k % 5 == 0:
                meta = ImageMeta(uav=u, capture_id=0, t=k * 0.05, stamp=now, cam_pos=pos,
                                 cam_rot=(1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0),
                                 intrinsics=Intrinsics(width=320, height=240, fx=300.0, fy=300.0, cx=160.0, cy=120.0))
                previews[u].put_bytes(pack_image(senders[u], meta, jpeg, now))
        if k % 20 == 0:
            d = Defect(area_px=40, bbox=(1, 1, 5, 5), centroid_px=(3.0, 3.0), contrast=9.0, pos=(60.0, 50.0 + k % 30, 28.0))
            bus.publisher(keys.defects(FLEET), COMMAND).put(
                DefectReport(uav=1, capture_id=k, stamp_capture=now, stamp_report=now, method="it+", defects=[d]))
        k += 1


def test_page_shows_moving_uavs_a_preview_and_the_defects(group, gateway) -> None:
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    port = free_port()
    svc = group.start("web", ["web", "--fleet", FLEET, "--multilink", "--listen-web", f"127.0.0.1:{port}",
                              *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_for("web up", 30), "\n".join(svc.lines)
    opts = Options()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1280,1100"):
        opts.add_argument(a)
    stop = threading.Event()
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "uav") as bus:
        feeder = threading.Thread(target=feed, args=(bus, stop), daemon=True)
        feeder.start()
        driver = webdriver.Chrome(service=Service(executable_path=DRIVER), options=opts)
        try:
            driver.get(f"http://127.0.0.1:{port}/")
            wait = WebDriverWait(driver, 30)
            wait.until(lambda d: d.find_element(By.ID, "conn").text == "live")
            wait.until(lambda d: d.execute_script("return document.querySelectorAll('#uavs tbody tr').length") == 3)

            def cell(uav: int, what: str) -> str | None:
                # one read in the page (the table is redrawn on every update: no element kept across updates)
                return driver.execute_script(
                    "const c = document.querySelector(`#uavs tr[data-uav='${arguments[0]}'] .${arguments[1]}`);"
                    "return c ? c.textContent : null", uav, what)

            def position(uav: int) -> str | None:
                return cell(uav, "pos")

            first = position(2)
            wait.until(lambda d: position(2) != first)  # UAV 2 moves
            assert cell(2, "mode") == "mission"
            wait.until(lambda d: d.execute_script(
                "const i = document.getElementById('preview-1'); return !!i && i.complete && i.naturalWidth === 320"))
            wait.until(lambda d: int(d.find_element(By.ID, "defect-count").text) >= 1)
            wait.until(lambda d: "mission" in d.find_element(By.ID, "events").text)
            wait.until(lambda d: d.execute_script("return window.skynet.snapshots") >= 5)  # the feed keeps coming
            ARTIFACTS.mkdir(exist_ok=True)
            time.sleep(0.5)  # one more frame drawn for the picture (nothing asserted on time)
            assert driver.save_screenshot(str(ARTIFACTS / "web-page.png"))
        finally:
            driver.quit()
            stop.set()
            feeder.join(5)
