"""docker compose: the compose files, overrides and image recipe (issues 6 and 14).

The real thing (an engine, a build, `up --exit-code-from gcs`, the report) is scripts/compose-e2e.sh,
which .ci/run runs; these tests check the files without an engine: Debian's docker-compose validates
every file and override, every service runs a skynet command its own parser accepts, and the
overrides cannot drift from the base file.
"""

import importlib
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from services.cli import COMMANDS
from services.netem.model import Impairment
from services.netem.sidecar import build_parser as sidecar_parser

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "docker-compose.yml"
EDGE_ENV = {"SKYNET_UAV": "2", "SKYNET_GATEWAY": "ground"}  # compose/edge.yml's mandatory variables

#: (compose arguments, extra environment) of every documented way to run compose
VARIANTS = [
    ([], {}),
    (["--profile", "netem"], {}),
    (["--profile", "tc-netem"], {}),
    (["--env-file", "compose/netem.env"], {}),
    (["--env-file", "compose/realtime.env"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/ports.yml"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/mavlink.yml"], {}),
    (["-f", "docker-compose.yml", "-f", "compose/camera.yml"], {}),
    (["-f", "compose/ground.yml"], {}),
    (["-f", "compose/edge.yml"], EDGE_ENV),
]

needs_compose = pytest.mark.skipif(shutil.which("docker-compose") is None,
                                   reason="Debian's docker-compose is not installed (apt-get install docker-compose); "
                                          ".ci/run installs it")


def _load(path: Path) -> dict:
    return yaml.safe_load(path.read_text())


def _services(path: Path = COMPOSE) -> dict:
    return _load(path)["services"]


def _defaults(text: str) -> str:
    """Compose interpolation with every variable at its default (``${X:-d}`` → d, ``$$`` → ``$``)."""
    text = re.sub(r"\$\{[A-Z0-9_]+:-([^}]*)\}", r"\1", text)
    return text.replace("$$", "$")


def _env(extra: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith(("SKYNET_", "NETEM", "COMPOSE_"))} | extra


@needs_compose
def test_every_compose_variant_validates():
    """`docker-compose config` of every variant, run side by side (each takes a second or two)."""
    procs = [(args, subprocess.Popen(["docker-compose", *args, "config", "-q"], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, cwd=ROOT, env=_env(env)))
             for args, env in VARIANTS]
    for args, proc in procs:
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, f"docker-compose {' '.join(args)} config: {err}"


@needs_compose
def test_a_split_edge_without_its_endpoints_is_refused():
    out = subprocess.run(["docker-compose", "-f", "compose/edge.yml", "config", "-q"], capture_output=True,
                         text=True, cwd=ROOT, env=_env({}))
    assert out.returncode != 0 and "SKYNET_UAV" in out.stderr


def _skynet_argv(name: str, svc: dict) -> list[str] | None:
    """The skynet command line a service runs (None for a side-car that runs no skynet command)."""
    entry = svc.get("entrypoint")
    cmd = [_defaults(c) for c in svc["command"]]
    if entry is None:
        return cmd
    if entry[:2] == ["sh", "-c"]:
        script = cmd[0]
        part = next((p for p in script.split(";") if "skynet " in p), None)
        if part is None:
            return None
        # the shell's own variables at typical values
        part = re.sub(r"\$\{?SKYNET_(SPEED)\}?", "4", part)
        part = re.sub(r"\$\{?SKYNET_(UAVS|UAV)\}?", "2", part)
        part = re.sub(r"\$\{?SKYNET_(APPEAR_TIMEOUT)\}?", "60", part)
        part = re.sub(r"\$\{?SKYNET_(FLEET)\}?", "demo", part)
        part = re.sub(r"\$\{?SKYNET_(GATEWAY)\}?", "ground", part)
        part = re.sub(r"\$\{?SKYNET_(HOME)\}?", "0,0,0", part)
        part = re.sub(r"\$\{?SKYNET_(CAMERA)\}?", "synthetic", part)
        part = re.sub(r"\$\{?[A-Za-z_]+\}?", "", part)  # the rest: empty (extra args, peers, the run name)
        argv = shlex.split(part.strip().removeprefix("exec "))
        assert argv[0] == "skynet", f"{name}: {argv}"
        return argv[1:]
    return None


@pytest.mark.parametrize("path", ["docker-compose.yml", "compose/mavlink.yml", "compose/camera.yml",
                                  "compose/ground.yml", "compose/edge.yml"])
def test_every_service_runs_a_skynet_command_that_parses(path):
    services = _services(ROOT / path)
    for name, svc in services.items():
        if "command" not in svc:
            continue
        argv = _skynet_argv(name, svc)
        if argv is None:
            continue
        assert argv[0] in COMMANDS, f"{name}: {argv[0]} is not a skynet command"
        module = importlib.import_module(COMMANDS[argv[0]][0])  # the service's own parser accepts them
        module.build_parser().parse_args(argv[1:])


def test_the_base_network_and_its_gcs():
    services = _services()
    assert {"gateway", "uav1", "uav2", "uav3", "planner", "detector", "gcs"} <= set(services)
    gcs = services["gcs"]
    assert gcs["restart"] == "no" and "/reports" in gcs["volumes"][0]
    script = gcs["command"][0]
    assert "chown" in script and "stat -c %u:%g /reports" in script  # the report belongs to ./reports' owner
    assert "exit $$rc" in script                                     # ... and the mission's verdict is gcs's exit
    # gcs starts when the others are up (health checks), every long-running service restarts on failure
    assert set(gcs["depends_on"]) == {"uav1", "uav2", "uav3", "planner", "detector"}
    for name in ("gateway", "uav1", "uav2", "uav3", "planner", "detector"):
        assert "healthcheck" in services[name] and services[name]["restart"] == "on-failure", name
    # one image, built once (by the gateway)
    assert [n for n, s in services.items() if "build" in s] == ["gateway"]
    assert len({s["image"] for s in services.values()}) == 1


def test_no_port_is_published_unless_asked_and_then_on_localhost():
    assert not any("ports" in s for s in _services().values())
    ports = _services(ROOT / "compose/ports.yml")["gateway"]["ports"]
    assert ports and all(_defaults(p).startswith("127.0.0.1:") for p in ports)
    for path in ("compose/ground.yml", "compose/edge.yml", "compose/mavlink.yml"):
        for svc in _services(ROOT / path).values():
            assert all(_defaults(p).startswith("127.0.0.1:") for p in svc.get("ports", [])), path


def test_netem_profile_is_a_user_space_side_car_that_fails_loudly():
    services = _services()
    env = dict(line.split("=", 1) for line in (ROOT / "compose/netem.env").read_text().splitlines()
               if line and not line.startswith("#"))
    assert "netem" in env["COMPOSE_PROFILES"].split(",")
    side = services["netem-uav2"]
    assert "netem" in side["profiles"] and side["restart"] == "no"
    assert side["entrypoint"] == ["python", "-m", "services.netem.sidecar"]
    args = sidecar_parser().parse_args([_defaults(c) for c in side["command"]])
    assert args.expect > 0  # an unused side-car ends the run
    assert not Impairment.parse(args.impair).is_null and not Impairment.parse(env["NETEM_UAV2"]).is_null
    # the env file points UAV 2 at its side-car, on both links of the multilink pair
    assert env["SKYNET_UAV2_UPLINK"] == "netem-uav2"
    uav2 = " ".join(services["uav2"]["command"])
    assert "tcp/${SKYNET_UAV2_UPLINK:-gateway}:7447" in uav2 and "udp/${SKYNET_UAV2_UPLINK:-gateway}:7448" in uav2
    # the kernel variant exits non-zero where tc netem cannot be applied (and so ends `up --exit-code-from`)
    tc = services["tc-netem-uav2"]
    assert "NET_ADMIN" in tc["cap_add"] and tc["network_mode"] == "service:uav2"
    assert "exit 2" in tc["command"][0] and tc["restart"] == "no"


def _drop(argv: list[str], options: set[str]) -> list[str]:
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a in options:
            skip = True
        else:
            out.append(a)
    return out


@pytest.mark.parametrize("path,changed", [("compose/mavlink.yml", {"--vehicle", "--mavlink", "--speed", "--camera"}),
                                          ("compose/camera.yml", {"--camera"})])
def test_overrides_change_only_what_they_say(path, changed):
    base, over = _services(), _services(ROOT / path)
    for name, svc in over.items():
        if "command" in svc:
            assert _drop(svc["command"], changed) == _drop(base[name]["command"], changed), f"{path}: {name}"


def test_image_builds_from_any_python_base_with_its_own_venv():
    docker = (ROOT / "Dockerfile").read_text()
    lines = [x for x in docker.splitlines() if x and not x.startswith("#")]
    assert lines[0].startswith("ARG BASE_IMAGE=python:3.11-slim") and lines[1] == "FROM ${BASE_IMAGE}"
    assert "python3 -m venv" in docker and "VIRTUAL_ENV=/opt/skynet" in docker  # PEP 668 bases too
    # dependencies (every service extra) in a layer before the code; the font cache made at build time
    assert docker.index("pip install -r") < docker.index("COPY services")
    assert "ARG EXTRAS=mavlink" in docker and "matplotlib.pyplot" in docker
    ignore = (ROOT / ".dockerignore").read_text().splitlines()
    assert ignore[ignore.index("*")] == "*" and "!services/" in ignore  # an allow-list: no .venv, reports, .git


def test_compose_check_reads_a_real_report(tmp_path):
    """scripts/compose_check.py (the e2e's assertions) on the report test's record: its failures are named."""
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        check = importlib.import_module("compose_check")
    finally:
        sys.path.pop(0)
    from services.gcs.report import write_report
    from tests.services.gcs.test_report import build_record

    rec = build_record()
    write_report(rec, tmp_path)
    assert check.main([str(tmp_path)]) == 1  # the record's mission failed (UAV 3 stopped half-way)
    report = json.loads((tmp_path / "report.json").read_text())
    record = json.loads((tmp_path / "record.json").read_text())
    fails, figures = check.check(report, record, impaired="uav2", delay_ms=100)
    assert any("mission failed" in f for f in fails) and any("impairment not applied" in f for f in fails)
    assert set(figures["telemetry_age_ms"]) == {1, 2, 3}
