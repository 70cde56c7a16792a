"""Shared fixtures: real services in real processes on loopback (no mock of the bus)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from protocol.bus import multilink_endpoints
from services.orchestration.process import free_port_pair
from tests.readiness import ServiceGroup

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
#: the most UAVs a test flies with the launcher's default development key set (the six-UAV mission)
DEV_KEYS_UAVS = 6


#: fixtures that start processes or Zenoh sessions: a test using one is in the integration layer (``network``)
NETWORK_FIXTURES = frozenset({"group", "gateway", "nominal_mission"})
#: what a test module's source says when it starts processes, opens Zenoh sessions or real sockets
NETWORK_WORDS = re.compile(r"\b(subprocess|Popen|ProcessGroup|run_node|spawn_node|fly_mission|zenoh\.open|Bus\(|"
                           r"socket\.socket|mavlink_connection|MavlinkSimVehicle|udpin:|udpout:)")


def _starts_processes(path: Path, cache: dict[Path, bool]) -> bool:
    if path not in cache:
        cache[path] = path.suffix == ".py" and path.name.startswith("test_") and bool(
            NETWORK_WORDS.search(path.read_text(errors="replace")))
    return cache[path]


#: whole missions that go out after the rest of the suite under xdist, each module a group of its own, in this order
#: (the long ones first, so that the short ones even out the two workers' ends, but the learned detector's CPU-heavy
#: one later; :func:`pytest_collection_modifyitems`):
#: sim-vehicle missions that share no session fixture with another module and whose checks are failure paths or wide
#: margins, so that a second mission beside them on the other worker decides nothing; the worker done with the rest
#: of the suite takes them instead of idling
LATE_MISSION_MODULES = (
    "tests/services/orchestration/test_compose.py",
    "tests/services/gcs/test_rogue_planner.py",
    "tests/services/web/test_mission_page.py",
    "tests/services/experiment/test_runner.py",
    "tests/services/detector/test_learned.py",
    "tests/services/gcs/test_mission.py",
    "tests/examples/test_examples.py",
    "tests/services/gcs/test_hostile_events.py",
)
#: the missions of the main group with the tightest clock (fault bounds in seconds, MAVLink sims behind the clock on
#: a loaded machine): first, in this order, while the other worker has the rest of the suite rather than a late
#: mission (two missions at once once stretched a gateway restart's blackout past its bound)
FIRST_MISSION_MODULES = (
    "tests/services/orchestration/test_fault_missions.py",
    "tests/services/orchestration/test_real_autopilots.py",
    "tests/services/orchestration/test_mavlink_mission.py",
    "tests/services/orchestration/test_autopilot_readiness.py",
    "tests/edge/vehicle/test_param_schemes.py",
    "tests/services/orchestration/test_px4_mission.py",
)


def _module(item: pytest.Item) -> str:
    return item.nodeid.split("::", 1)[0]


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the groups
def pytest_collection_modifyitems(config, items):
    """Whole missions (marker ``mission``) run one after another on one pytest-xdist worker (the group
    ``mission``) while the other worker takes the rest of the suite (scripts/test.sh, ``--dist loadgroup``), the
    missions of :data:`FIRST_MISSION_MODULES` first; those of :data:`LATE_MISSION_MODULES` (a group per module)
    go out after the rest of the suite, to whichever worker is free. Under xdist the items are put in that order
    (:func:`pytest_configure` keeps it); without xdist nothing is reordered.

    A test that starts processes or Zenoh sessions (a fixture of :data:`NETWORK_FIXTURES`, or a module whose
    source matches :data:`NETWORK_WORDS`) gets the ``network`` marker, and a mission gets it too: the fast
    loop (scripts/test-fast.sh) leaves them out."""
    seen: dict[Path, bool] = {}
    missions: list[pytest.Item] = []
    rest: list[pytest.Item] = []
    late: list[pytest.Item] = []
    for item in items:
        if item.get_closest_marker("mission"):
            module = _module(item)
            if module in LATE_MISSION_MODULES:
                item.add_marker(pytest.mark.xdist_group(f"mission-late:{module}"))
                late.append(item)
            else:
                item.add_marker(pytest.mark.xdist_group("mission"))
                missions.append(item)
            item.add_marker(pytest.mark.network)
        else:
            if NETWORK_FIXTURES & set(getattr(item, "fixturenames", ())) or _starts_processes(item.path, seen):
                item.add_marker(pytest.mark.network)
            rest.append(item)
    if hasattr(config, "workerinput"):  # an xdist worker: its items in the order the groups go out
        rank = {m: k for k, m in enumerate(FIRST_MISSION_MODULES)}
        missions.sort(key=lambda it: rank.get(_module(it), len(rank)))  # stable: the others in collection order
        late.sort(key=lambda it: LATE_MISSION_MODULES.index(_module(it)))
        items[:] = missions + rest + late


def pytest_configure(config):
    """xdist sends groups out largest first (``--loadscope-reorder``, its default); off, so that they go out in
    the order :func:`pytest_collection_modifyitems` gives them."""
    if getattr(config.option, "loadscopereorder", None):
        config.option.loadscopereorder = False


@pytest.fixture(scope="session", autouse=True)
def dev_keys(tmp_path_factory):
    """The launcher's default development key set for this test session: a folder of its own (``$SKYNET_KEYS``,
    inherited by every process the tests start), never the user's ``.keys/dev``; made once for the largest fleet
    a test flies, so no mission rotates it while another test's network reads it."""
    from services.orchestration import trustmode

    folder = tmp_path_factory.mktemp("dev-keys") / "dev"
    old = os.environ.get(trustmode.KEYS_ENV)
    os.environ[trustmode.KEYS_ENV] = str(folder)
    yield trustmode.dev_keys(folder, DEV_KEYS_UAVS)
    if old is None:
        os.environ.pop(trustmode.KEYS_ENV, None)
    else:
        os.environ[trustmode.KEYS_ENV] = old


@pytest.fixture
def group():
    """A process group whose children are all stopped after the test."""
    g = ServiceGroup(echo=None)
    yield g
    g.stop()


@pytest.fixture
def gateway(group):
    """A running ``skynet gateway`` (router) with the multilink endpoints; yields the endpoints."""
    tcp, udp = free_port_pair()
    endpoints = multilink_endpoints("127.0.0.1", tcp, udp)
    # no ingress limit on states (services/gateway/ingress.py, tested in tests/services/gateway/test_ingress.py):
    # the bus tests send states back to back through this router
    svc = group.start("gateway", ["gateway", "--fleet", "test", "--multilink", "--period-s", "0.3",
                                  "--state-ingress-hz", "0",
                                  *[a for e in endpoints for a in ("--listen", e)]], ready=True)
    assert svc.wait_ready(20), "\n".join(svc.lines)  # its ready signal (protocol.readiness)
    return endpoints


@dataclass(frozen=True)
class MissionRun:
    """A finished ``skynet mission``: its process and its report folder (read only)."""

    proc: subprocess.CompletedProcess
    out: Path

    def report(self) -> dict:
        return json.loads((self.out / "report.json").read_text())

    def record(self) -> dict:
        return json.loads((self.out / "record.json").read_text())

    def failure(self) -> str:
        """What to print when an assertion on this run fails."""
        return self.proc.stdout[-3000:] + self.proc.stderr[-3000:]

    def flown(self, uavs: int = 3, rms_bound_m: float = 1.0) -> dict:
        """The report of a mission that flew as planned (exit 0, success, every UAV at the goal, every capture point
        imaged, formation RMS under ``rms_bound_m``); AssertionError with the output otherwise."""
        assert self.proc.returncode == 0, self.failure()
        report = self.report()
        assert report["success"] and not report["failures"], report["failures"]
        assert len(report["uavs"]) == uavs and all(fig["reached_goal"] for fig in report["uavs"].values()), report["uavs"]
        assert report["captures"]["planned"] > 0 and report["captures"]["imaged"] == report["captures"]["planned"]
        assert report["formation"]["rms_m"] < rms_bound_m, report["formation"]
        return report


#: the optional extras' packages (pyproject.toml): the main job (scripts/run.sh) installs none of them
EXTRA_PACKAGES = frozenset({"pymavlink", "mavsdk", "selenium"})

_BLOCK = """
import importlib.abc, sys

class _Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in {blocked!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None

sys.meta_path.insert(0, _Block())
"""


def env_without(folder: Path, blocked: frozenset[str] | set[str] = EXTRA_PACKAGES) -> dict[str, str]:
    """An environment whose Pythons cannot import the ``blocked`` packages (a ``sitecustomize`` in ``folder``
    that refuses them: the same failure as a venv without the extra), inherited by every process they start."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(_BLOCK.format(blocked=set(blocked)))
    path = os.pathsep.join(p for p in (str(folder), str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path}


def fly_mission(out: Path, *argv: str, timeout: float = 400, env: dict[str, str] | None = None) -> MissionRun:
    """``skynet mission --quiet --out OUT ARGV...`` in a subprocess (the whole network on loopback)."""
    try:
        proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--quiet", "--out", str(out), *argv],
                              cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired as exc:  # below pytest's own timeout (pyproject.toml): say what it printed
        pytest.fail(f"skynet mission {' '.join(argv)} still running after {timeout:.0f} s; it printed:\n"
                    f"{_text(exc.stdout)[-3000:]}{_text(exc.stderr)[-3000:]}", pytrace=False)
    return MissionRun(proc, out)


def _text(data: bytes | str | None) -> str:
    return data.decode(errors="replace") if isinstance(data, bytes) else (data or "")


@pytest.fixture(scope="session")
def nominal_mission(tmp_path_factory) -> MissionRun:
    """The paper's mission as README's first command flies it (three UAVs, secure, recorded, none of the optional
    extras importable: scripts/run.sh installs none), at 8x, flown once per session: the tests that check
    different things of the same nominal mission (its report, its MCAP rebuild and replay) read this one run
    instead of each flying their own (CI time)."""
    root = tmp_path_factory.mktemp("nominal")
    return fly_mission(root / "report", "--speed", "8", timeout=300, env=env_without(root / "no-extras"))


@pytest.fixture(scope="session")
def nominal_report_again(nominal_mission, tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    """``skynet report`` of the nominal mission's folder (the mission log read back) into a folder of its own, run
    once per session: its process and that folder. The launcher's test (tests/services/orchestration/test_launcher.py)
    and the report-again test of the folder (tests/services/gcs/test_report_again.py) check the same run (CI time)."""
    again = tmp_path_factory.mktemp("nominal-again") / "again"
    proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(nominal_mission.out), "--out", str(again)],
                          capture_output=True, text=True, timeout=240)
    return proc, again


@pytest.fixture(scope="session")
def impaired_secure_mission(tmp_path_factory) -> MissionRun:
    """The mission with 200 ms each way on every link (reliable ones too, from 4 s on, once the sessions are
    open), the accept guard in front of the gateway (the default) and a key set of its own, at 8x, flown once per session:
    the test of the plan under delay (tests/services/orchestration/test_launcher.py) and the test of the
    proxied links' TLS and ACL (tests/services/gateway/test_trust_seams.py) read this one run (CI time)."""
    root = tmp_path_factory.mktemp("impaired")
    return fly_mission(root / "report", "--speed", "8", "--keys", str(root / "keys"),
                       "--impair", "all=after 4s delay 200ms", timeout=300)


@pytest.fixture(scope="session")
def slow_boot_guided_mission(tmp_path_factory) -> MissionRun:
    """The mission with ``--vehicle mavlink`` in GUIDED at 8x, secure, on sim autopilots that take three times
    ArduCopter's start-up (GUIDED allowed 126 simulated s after power-on: ~16 wall s, later than the plan is
    ready), flown once per session: the test of the MAVLink GUIDED mission
    (tests/services/orchestration/test_mavlink_mission.py) and the test that the ground station waits for
    autopilots still starting (tests/services/orchestration/test_autopilot_readiness.py) read this one run (CI time)."""
    pytest.importorskip("pymavlink", reason="--vehicle mavlink needs the 'mavlink' extra")
    root = tmp_path_factory.mktemp("guided-slow-boot")
    return fly_mission(root / "report", "--vehicle", "mavlink", "--speed", "8", "--flight", "guided",
                       "--sim-boot-scale", "3", timeout=300)


def wait_until(pred, timeout: float = 20.0, poll: float = 0.02) -> bool:
    """Poll ``pred`` until it holds or ``timeout`` seconds pass; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(poll)
    return bool(pred())


def run_node(code: str, timeout: float = 30.0) -> subprocess.CompletedProcess:
    """Run a small Python program in its own process (a second Zenoh node)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=timeout)


def spawn_node(code: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
