"""An event with hostile text, published with uav2's own certificate on uav2's own event key through the
launcher's secure network (``skynet up``), reaches the ground station's stderr (``skynet gcs --keys``)
escaped; the same UAV's event claiming to come from the ground station is refused, not shown."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.keyset import KeySet
from protocol.links import COMMAND
from protocol.messages import Event, Level
from tests.conftest import ROOT
from tests.protocol.test_textsafe import HOSTILE
from tests.readiness import interrupt, launched

FLEET = "hostile"


def _reader(proc: subprocess.Popen, lines: list[str]) -> threading.Thread:
    def pump() -> None:
        for line in proc.stdout:
            lines.append(line)

    t = threading.Thread(target=pump, daemon=True)
    t.start()
    return t


def _wait(pred, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.1)
    return pred()


@pytest.mark.mission
def test_hostile_event_text_reaches_the_ground_station_stderr_escaped(dev_keys, tmp_path):
    gcs_lines: list[str] = []
    with launched(["up", "--uavs", "2", "--speed", "4", "--fleet", FLEET, "--camera", "none"], cwd=tmp_path):
        endpoints = json.loads((tmp_path / ".skynet" / "network.json").read_text())["endpoints"]
        gcs = subprocess.Popen([sys.executable, "-m", "services.cli", "gcs", "--keys", str(dev_keys),
                                "--fleet", FLEET, "--uavs", "2", "--speed", "4", "--quiet", "--no-record",
                                "--multilink", *[a for e in endpoints for a in ("-e", e)]],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace")
        _reader(gcs, gcs_lines)
        try:
            ks = KeySet(dev_keys, "uav2")
            cfg = BusConfig(mode="client", connect=endpoints, multilink=True, tls_ca=str(ks.ca),
                            tls_cert=str(ks.tls_cert), tls_key=str(ks.tls_key))
            with Bus(cfg, FLEET, "rogue-uav2") as rogue:
                pub = rogue.publisher(keys.event(FLEET, 2), COMMAND)
                # until the ground station has subscribed and logged it (it starts after this session)
                for _ in range(120):
                    pub.put(Event(source="gcs", stamp=time.time(), kind="plan-refused", level=Level.WARNING,
                                  text="FORGED-SOURCE"))
                    pub.put(Event(source="uav/2", stamp=time.time(), kind="pilot-mode", level=Level.WARNING,
                                  text=HOSTILE))
                    if _wait(lambda: any("event from uav/2: pilot-mode" in ln for ln in gcs_lines), 0.5):
                        break
        finally:
            interrupt(gcs)
    out = "".join(gcs_lines)
    logged = [ln for ln in gcs_lines if "event from uav/2: pilot-mode" in ln]
    assert logged, out[-3000:]
    assert "\x1b" not in out and "\x07" not in out and "\x9b" not in out and "\u202e" not in out, repr(out[-2000:])
    line = logged[0]
    assert "\\x1b[2J\\x1b[H\\x1b]0;pwned\\x07\\x1b]52;c;cm0gLXJmIH4=\\x07\\x0d\\x0a12:00:00 gcs INFO mission" in line
    assert "<img src=x onerror=alert(1)>" in line  # printable text stays as it was
    assert "FORGED-SOURCE" not in out and "event from gcs" not in out  # uav2 may not speak as the ground station
