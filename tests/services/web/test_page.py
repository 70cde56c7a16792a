"""The live web page in a real headless browser (Debian's chromium through selenium + chromium-driver).

A ``skynet web`` process follows the bus; this test puts three moving UAVs, their live previews,
an event and a defect report on the bus, and a headless chromium loads the page at the URL the
service printed (with its access token): the UAVs' positions change between two readings, a preview
image is decoded, the detections show; a screenshot is saved to ``tests/artifacts/web-page.png``
(git-ignored). Hostile event text on uav2's, the planner's and the detector's own event keys is shown
as text and runs no script.
"""

from __future__ import annotations

import re
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
#: event texts that run script if a page puts them in as HTML
HOSTILE = ('<img src=x onerror="window.__xss=(window.__xss||0)+1">',
           '<svg onload="window.__xss=(window.__xss||0)+1"></svg>',
           '</div><script>window.__xss=(window.__xss||0)+1</script>')
#: (key, source) of the event keys the hostile texts arrive on: a UAV's, the planner's, the detector's
HOSTILE_KEYS = ((keys.event(FLEET, 2), "uav/2"), (keys.rcu_event(FLEET, "planner"), "planner"),
                (keys.rcu_event(FLEET, "detector"), "detector"))
ARTIFACTS = Path(__file__).resolve().parents[2] / "artifacts"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium drives the browser")
pytestmark = [pytest.mark.browser,
              pytest.mark.skipif(not (CHROMIUM and DRIVER),
                                 reason="needs Debian's chromium and chromium-driver (.ci/run installs them)")]


def feed(bus: Bus, stop: threading.Event) -> None:
    states = {u: bus.publisher(keys.state(FLEET, u), TELEMETRY) for u in (1, 2, 3)}
    previews = {u: bus.publisher(keys.preview(FLEET, u), IMAGERY) for u in (1, 2, 3)}
    senders = {u: RtpSender(ssrc_for(u, 1)) for u in (1, 2, 3)}
    gcs_events = bus.publisher(keys.gcs_event(FLEET), COMMAND)
    hostile = [(bus.publisher(key, COMMAND), source) for key, source in HOSTILE_KEYS]
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
        if k % 10 == 0:  # again and again: whenever the page looks, they are in its timeline
            gcs_events.put(Event(source="gcs", stamp=now, kind="plan-refused", text="mission"))
            for pub, source in hostile:
                for text in HOSTILE:
                    pub.put(Event(source=source, stamp=now, kind="pilot-mode", text=text))
        if k % 20 == 0:
            d = Defect(area_px=40, bbox=(1, 1, 5, 5), centroid_px=(3.0, 3.0), contrast=9.0, pos=(60.0, 50.0 + k % 30, 28.0))
            bus.publisher(keys.defects(FLEET), COMMAND).put(
                DefectReport(uav=1, capture_id=k, stamp_capture=now, stamp_report=now, method="it+", defects=[d]))
        k += 1


def d_text(driver, element_id: str) -> str:
    return driver.execute_script("return document.getElementById(arguments[0]).textContent", element_id)


def test_page_shows_moving_uavs_a_preview_the_defects_and_hostile_text_as_text(group, gateway) -> None:
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    port = free_port()
    svc = group.start("web", ["web", "--fleet", FLEET, "--multilink", "--web", f"127.0.0.1:{port}",
                              *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    printed = [m.group(1) for line in svc.lines if (m := re.search(r"web page at (\S+)", line))]
    assert printed and re.fullmatch(rf"http://127\.0\.0\.1:{port}/\?token=[A-Za-z0-9_-]{{16,}}", printed[0]), svc.lines
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
            driver.get(f"http://127.0.0.1:{port}/")  # without the token: refused, no page
            assert "access token" in driver.find_element(By.TAG_NAME, "body").text
            assert driver.execute_script("return window.skynet === undefined")
            driver.get(printed[0])
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
            wait.until(lambda d: int(d.find_element(By.ID, "detections").text) >= 1)
            assert d_text(driver, "defect-count") == "-"  # no captures folder: no deduplicated count to show
            wait.until(lambda d: "mission" in d.find_element(By.ID, "events").text)
            # hostile text from each of the three keys is shown as text, and no element or script came of it
            for _, source in HOSTILE_KEYS:
                wait.until(lambda d: all(f"{source} pilot-mode {t}" in d.find_element(By.ID, "events").text for t in HOSTILE))
            assert driver.execute_script("return document.querySelectorAll('#events img, #events svg, "
                                         "#events script').length") == 0
            assert driver.execute_script("return window.__xss === undefined")
            wait.until(lambda d: d.execute_script("return window.skynet.snapshots") >= 5)  # the feed keeps coming
            ARTIFACTS.mkdir(exist_ok=True)
            time.sleep(0.5)  # one more frame drawn for the picture (nothing asserted on time)
            assert driver.save_screenshot(str(ARTIFACTS / "web-page.png"))
        finally:
            driver.quit()
            stop.set()
            feeder.join(5)
