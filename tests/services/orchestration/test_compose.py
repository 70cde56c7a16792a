"""The product as a user composes it, in the default secure mode (mutual TLS, certificate ACL; no --insecure):

``skynet up --video h264 --web :PORT`` serves decodable H.264 streams (FFmpeg through PyAV from the SDP files
``--sdp-dir`` wrote; GStreamer's ``rtph264depay``) and a page with live data; ``skynet video``, ``skynet web``
and ``skynet replay`` started beside it with no bus options attach to it through ``.skynet/network.json``
(each with its own identity: JPEG video decoded by FFmpeg and GStreamer, the page live, a replay seen under
the replay fleet and never on the live one); what cannot attach says why in one line. The network runs in a
temporary working folder with its own development key set.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from protocol import codec, keys
from protocol.messages import Mode, VehicleState
from services.attach import NETWORK_FILE
from services.orchestration.process import free_port
from services.recording.mcap_log import McapLog
from tests.conftest import ROOT, wait_until
from tests.readiness import ReadyPipe

av = pytest.importorskip("av")
GST = shutil.which("gst-launch-1.0")
pytestmark = pytest.mark.mission  # a whole network of processes: one at a time with the missions
WANTED = 5
FLEET = keys.DEFAULT_FLEET
#: the web page's access token, handed to every page this module starts (``SKYNET_WEB_TOKEN``)
TOKEN = "composed-test-token-0123456789"


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1", "SKYNET_WEB_TOKEN": TOKEN}


def skynet(cwd: Path, *argv: str, timeout: float = 90) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "services.cli", *argv], cwd=cwd, env=_env(), capture_output=True,
                          text=True, timeout=timeout)


class Tool:
    """A ``skynet`` command running in the background, its output collected."""

    def __init__(self, cwd: Path, *argv: str):
        self.ready = ReadyPipe()  # its ready signal (protocol.readiness)
        self.proc = subprocess.Popen([sys.executable, "-m", "services.cli", *argv], cwd=cwd,
                                     env=self.ready.env(_env()), pass_fds=self.ready.pass_fds,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.ready.started()
        self.lines: list[str] = []
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, text: str, timeout: float = 60) -> bool:
        return wait_until(lambda: any(text in ln for ln in self.lines) or self.proc.poll() is not None, timeout) \
            and any(text in ln for ln in self.lines)

    def wait_ready(self, timeout: float = 60) -> tuple[str, str] | None:
        """``(role, name)`` once the tool signalled it is up; None if it ended first."""
        return self.ready.wait(self.proc, timeout)

    def text(self) -> str:
        return "\n".join(self.lines[-60:])

    def stop(self) -> int | None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        return self.proc.returncode


class Network:
    def __init__(self, cwd: Path, tool: Tool, web_port: int, video_port: int):
        self.cwd, self.tool, self.web_port, self.video_port = cwd, tool, web_port, video_port

    def description(self) -> dict:
        return json.loads((self.cwd / NETWORK_FILE).read_text())


@pytest.fixture(scope="module")
def network(tmp_path_factory):
    cwd = tmp_path_factory.mktemp("composed")
    web_port, video_port = free_port(), free_port() & ~1
    tool = Tool(cwd, "up", "--uavs", "3", "--video", "h264", "--sdp-dir", "sdp", "--preview-port", str(video_port),
                "--web", f":{web_port}")
    net = Network(cwd, tool, web_port, video_port)
    try:
        ok = all(tool.wait_for(f"{name} up", 120) for name in ("router", "planner", "detector", "video", "web"))
        assert ok and tool.wait_for("network described in", 30), tool.text()
        yield net
    finally:
        code = tool.stop()
        assert code == 0, tool.text()
        assert not (cwd / NETWORK_FILE).exists()  # removed at shutdown
        assert not any("restarting it" in ln for ln in tool.lines), tool.text()  # nothing needed the supervisor


def _decode_sdp(sdp: Path, wanted: int = WANTED) -> list[tuple[int, int]]:
    """(width, height) of the first ``wanted`` pictures FFmpeg decodes from the stream an SDP file describes."""
    shapes = []
    with av.open(str(sdp), format="sdp", timeout=30,
                 options={"protocol_whitelist": "file,udp,rtp", "reorder_queue_size": "0"}) as c:
        for frame in c.decode(video=0):
            shapes.append((frame.width, frame.height))
            if len(shapes) >= wanted:
                break
    return shapes


def _gst_h264(port: int, wanted: int = WANTED) -> int:
    """Pictures decoded from GStreamer's ``rtph264depay`` (access units) by FFmpeg's decoder."""
    proc = subprocess.Popen([GST, "-q", "udpsrc", f"port={port}",
                             "caps=application/x-rtp,media=video,clock-rate=90000,encoding-name=H264,payload=96",
                             "!", "rtph264depay", "!", "video/x-h264,stream-format=byte-stream,alignment=au", "!",
                             "fdsink", "fd=1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    decoder = av.CodecContext.create("h264", "r")
    n = 0
    deadline = time.monotonic() + 40
    try:
        os.set_blocking(proc.stdout.fileno(), False)
        while n < wanted and time.monotonic() < deadline and proc.poll() is None:
            chunk = proc.stdout.read(65536)
            if not chunk:
                time.sleep(0.05)
                continue
            for packet in decoder.parse(chunk):
                try:
                    n += len(decoder.decode(packet))
                except av.error.InvalidDataError:  # joined a live stream mid-GOP: until its next keyframe
                    if n:
                        raise
    finally:
        proc.kill()
        proc.wait(5)
    return n


def _gst_jpeg(port: int, wanted: int = WANTED) -> int:
    """320x240 pictures GStreamer's ``rtpjpegdepay ! jpegdec`` decodes (the caps filter refuses any other size)."""
    w, h = 320, 240
    proc = subprocess.Popen([GST, "-q", "udpsrc", f"port={port}",
                             "caps=application/x-rtp,media=video,clock-rate=90000,encoding-name=JPEG,payload=26",
                             "!", "rtpjpegdepay", "!", "jpegdec", "!", "videoconvert", "!",
                             f"video/x-raw,format=BGR,width={w},height={h}", "!", "fdsink", "fd=1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    got = []

    def read() -> None:
        while len(got) < wanted:
            buf = proc.stdout.read(w * h * 3)
            if len(buf) < w * h * 3:
                return
            got.append(np.frombuffer(buf, np.uint8).reshape(h, w, 3).mean())

    t = threading.Thread(target=read, daemon=True)
    t.start()
    t.join(40)
    proc.kill()
    proc.wait(5)
    return len(got)


def _snapshot(port: int) -> dict:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/snapshot.json?token={TOKEN}", timeout=10) as r:
        return json.loads(r.read())


def _live_uavs(port: int) -> set[str]:
    try:
        snap = _snapshot(port)
    except OSError:
        return set()
    return {u for u, s in snap.get("uavs", {}).items() if s.get("pos") is not None}


def test_up_streams_h264_that_ffmpeg_and_gstreamer_decode(network) -> None:
    d = network.description()
    assert d["tls"] and d["fleet"] == FLEET and all(e.startswith("tls/") for e in d["endpoints"])
    assert "key" not in json.dumps({k: v for k, v in d.items() if k != "keys"}).lower()  # names no secret
    sdp = network.cwd / "sdp" / "uav1-preview.sdp"
    assert "H264/90000" in sdp.read_text() and f"m=video {network.video_port} " in sdp.read_text()
    shapes = _decode_sdp(sdp)
    assert len(shapes) == WANTED and set(shapes) == {(320, 240)}, network.tool.text()
    if GST is None:
        pytest.skip("GStreamer half: needs Debian's gstreamer1.0-tools and -plugins-good (.ci/run installs them)")
    assert _gst_h264(network.video_port + 2) >= WANTED  # UAV 2's stream


def test_up_serves_the_page_with_live_data(network) -> None:
    assert wait_until(lambda: _live_uavs(network.web_port) == {"1", "2", "3"}, 30), _snapshot(network.web_port)
    snap = _snapshot(network.web_port)
    assert all(s["rate_hz"] > 1 for s in snap["uavs"].values()), snap
    with urllib.request.urlopen(f"http://127.0.0.1:{network.web_port}/?token={TOKEN}", timeout=10) as r:
        assert b"SkyNet" in r.read()
    # the WebSocket the page reads: a static document, then snapshots
    import asyncio

    import aiohttp

    async def ws() -> list[dict]:
        async with aiohttp.ClientSession() as s, s.ws_connect(f"http://127.0.0.1:{network.web_port}/ws?token={TOKEN}") as w:
            return [json.loads((await w.receive(timeout=10)).data) for _ in range(3)]

    docs = asyncio.run(ws())
    assert any(d.get("type") == "snapshot" and d.get("uavs") for d in docs), docs


def test_video_attaches_with_no_options_and_streams_jpeg_that_ffmpeg_and_gstreamer_decode(network) -> None:
    port = free_port() & ~1
    tool = Tool(network.cwd, "video", "--codec", "mjpeg", "--preview-port", str(port), "--sdp-dir", "sdp-jpeg",
                "--uavs", "3")
    try:
        assert tool.wait_ready(60) == ("video", "video"), tool.text()
        assert "with video's identity" in tool.text()
        sdp = network.cwd / "sdp-jpeg" / "uav3-preview.sdp"
        assert "JPEG/90000" in sdp.read_text()
        shapes = _decode_sdp(sdp)
        assert len(shapes) == WANTED and set(shapes) == {(320, 240)}, tool.text()
        if GST is not None:
            assert _gst_jpeg(port) >= WANTED, tool.text()  # UAV 1's stream
    finally:
        assert tool.stop() == 0, tool.text()
    if GST is None:
        pytest.skip("GStreamer half: needs Debian's gstreamer1.0-tools and -plugins-good (.ci/run installs them)")


def _recording(path: Path, uav: int = 9, n: int = 40) -> Path:
    """A small mission log (MCAP) of one UAV's states on the live fleet's keys."""
    log = McapLog(path)
    for k in range(n):
        msg = VehicleState(uav=uav, seq=k, t=k * 0.05, stamp=time.time(), pos=(30.0, 5.0 + k * 0.1, 10.0),
                           vel=(0, 2, 0), att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.MISSION)
        log.write_sample(keys.state(FLEET, uav), codec.encode(msg), 100.0 + k * 0.05)
    log.close()
    return path


def test_web_and_replay_attach_and_a_replay_never_reaches_the_live_fleet(network, tmp_path: Path) -> None:
    live_port, replay_port = free_port(), free_port()
    live = Tool(network.cwd, "web", "--web", f":{live_port}")
    shown = Tool(network.cwd, "web", "--web", f":{replay_port}", "--fleet", keys.replay_fleet(FLEET))
    mcap = _recording(tmp_path / "mission.mcap")
    try:
        assert live.wait_ready(60) == shown.wait_ready(60) == ("web", "web"), live.text() + shown.text()
        assert wait_until(lambda: _live_uavs(live_port) >= {"1", "2", "3"}, 30), live.text()
        # told to write on the live fleet: the replay identity may not, the live page never shows it
        forced = skynet(network.cwd, "replay", str(mcap), "--speed", "0", "--reliable", "--as-fleet", FLEET)
        assert forced.returncode == 0, forced.stderr
        # by default under the replay fleet, where the replay page shows it
        done = skynet(network.cwd, "replay", str(mcap), "--speed", "0", "--reliable")
        assert done.returncode == 0 and "as fleet demo-replay" in done.stderr, done.stderr
        assert wait_until(lambda: "9" in _live_uavs(replay_port), 20), shown.text()
        time.sleep(1.0)
        assert "9" not in _live_uavs(live_port)
        assert _live_uavs(replay_port) == {"9"}  # the live fleet is not on the replay page either
    finally:
        assert live.stop() == 0, live.text()
        assert shown.stop() == 0, shown.text()


def _one_line_error(proc: subprocess.CompletedProcess, *words: str) -> None:
    err = proc.stderr.strip()
    assert proc.returncode == 2, (proc.returncode, proc.stdout, err)
    assert "Traceback" not in err and "Timeout!" not in err and "No peer specified" not in err, err
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err


def test_what_cannot_attach_says_why_in_one_line(network, tmp_path: Path) -> None:
    # no network in this folder
    _one_line_error(skynet(tmp_path, "web", "--web", f":{free_port()}"), "no network running here")
    # a description whose launcher has ended
    stale = tmp_path / "stale.json"
    desc = network.description()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale.write_text(json.dumps({**desc, "pid": dead.pid}))
    _one_line_error(skynet(tmp_path, "video", "--network", str(stale)), "has ended")
    # a fleet the network does not carry
    _one_line_error(skynet(network.cwd, "video", "--fleet", "other"), "carries fleet demo")
    # another key set (another CA)
    other = tmp_path / "other-keys"
    assert skynet(tmp_path, "keys", "init", str(other), "--uavs", "1").returncode == 0
    _one_line_error(skynet(network.cwd, "replay", str(_recording(tmp_path / "m.mcap")), "--keys", str(other)),
                    "not the running network's key set")
    # the right endpoints, the wrong identity: Zenoh's refusal turned into a sentence
    eps = [a for e in desc["endpoints"] for a in ("-e", e)]
    _one_line_error(skynet(tmp_path, "web", "--web", f":{free_port()}", "--multilink", *eps, "--keys",
                           str(other), timeout=120), "no gateway answered", "is it this network's key set")


def test_up_tells_a_service_that_cannot_start_and_stops_restarting_it(tmp_path: Path) -> None:
    (tmp_path / "sdp-file").write_text("a file where the SDP folder should be\n")
    tool = Tool(tmp_path, "up", "--uavs", "1", "--video", "h264", "--sdp-dir", "sdp-file",
                "--preview-port", str(free_port() & ~1))
    try:
        assert tool.wait_for("video did not start", 120), tool.text()
        line = next(ln for ln in tool.lines if "video did not start" in ln)
        assert "exited 3 times without coming up" in line and "sdp-file" in line, line
        time.sleep(3.0)
        assert sum("restarted by the supervisor" in ln for ln in tool.lines) == 2, tool.text()  # and no more
        assert tool.proc.poll() is None  # the rest of the network keeps running
    finally:
        assert tool.stop() == 0, tool.text()


def test_a_mission_whose_video_cannot_start_fails_and_says_why(tmp_path: Path) -> None:
    from tests.conftest import fly_mission

    (tmp_path / "sdp-file").write_text("a file where the SDP folder should be\n")
    run = fly_mission(tmp_path / "report", "--speed", "8", "--video", "h264", "--sdp-dir",
                      str(tmp_path / "sdp-file"), "--preview-port", str(free_port() & ~1), timeout=400)
    assert run.proc.returncode != 0, run.failure()
    terminal = run.proc.stdout + run.proc.stderr
    assert "video did not start" in terminal and "mission failed: video did not start" in terminal, run.failure()
    report = run.report()
    assert not report["success"] and any(f.startswith("video did not start") for f in report["failures"])
    outcome = next(ln for ln in (run.out / "report.md").read_text().splitlines() if ln.startswith("Outcome:"))
    assert "video did not start" in outcome
    faults = report["faults"]
    assert faults["faults"] == []  # nothing was injected
    assert [x["action"] for x in faults["supervision"]] == ["supervisor-restart", "supervisor-restart",
                                                           "start-failed"], faults["supervision"]
    assert faults["seen_again"] == []


def test_a_secure_mission_with_video_streams_jpeg_that_ffmpeg_and_gstreamer_decode(tmp_path: Path) -> None:
    """README's operator recipe, ``skynet mission --video mjpeg --sdp-dir DIR``, in the default secure mode."""
    port = free_port() & ~1
    mission = Tool(tmp_path, "mission", "--quiet", "--speed", "8", "--out", str(tmp_path / "report"), "--video",
                   "mjpeg", "--sdp-dir", "sdp", "--preview-port", str(port))
    try:
        sdp = tmp_path / "sdp" / "uav2-preview.sdp"
        assert wait_until(sdp.exists, 120), mission.text()
        assert (tmp_path / NETWORK_FILE).exists()  # a mission describes its network too
        assert "JPEG/90000" in sdp.read_text()
        shapes = _decode_sdp(sdp)
        assert len(shapes) == WANTED and set(shapes) == {(320, 240)}, mission.text()
        if GST is not None:
            assert _gst_jpeg(port) >= WANTED, mission.text()  # UAV 1's stream
        assert mission.proc.wait(400) == 0, mission.text()
    finally:
        mission.stop()
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["success"] and report["faults"]["supervision"] == [], report["failures"]
    assert not (tmp_path / NETWORK_FILE).exists()
    services = (tmp_path / "report" / "services.log").read_text()
    assert "video up" in services and "restarting it" not in services
    if GST is None:
        pytest.skip("GStreamer half: needs Debian's gstreamer1.0-tools and -plugins-good (.ci/run installs them)")
