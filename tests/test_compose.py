"""docker compose runs the same network with the same commands as the launcher (issue 6)."""

import importlib
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from services.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "docker-compose.yml"


def _services():
    return yaml.safe_load(COMPOSE.read_text())["services"]


@pytest.mark.skipif(shutil.which("docker-compose") is None,
                    reason="Debian's docker-compose is not installed (apt-get install docker-compose); .ci/run installs it")
def test_compose_file_validates():
    for profile in ([], ["--profile", "netem"]):
        out = subprocess.run(["docker-compose", "-f", str(COMPOSE), *profile, "config", "-q"], capture_output=True,
                             text=True, cwd=ROOT)
        assert out.returncode == 0, out.stderr


def test_every_service_runs_a_skynet_command_that_parses():
    services = _services()
    assert {"gateway", "uav1", "uav2", "uav3", "planner", "detector", "gcs"} <= set(services)
    for name, svc in services.items():
        if svc.get("entrypoint"):  # the netem side-car runs tc, not skynet
            continue
        cmd = svc["command"]
        assert cmd[0] in COMMANDS, f"{name}: {cmd[0]} is not a skynet command"
        # the service's own parser accepts exactly these arguments
        module = importlib.import_module(COMMANDS[cmd[0]][0])
        module.build_parser().parse_args(cmd[1:])


def test_netem_profile_needs_net_admin_and_tc():
    side = _services()["netem-uav2"]
    assert "NET_ADMIN" in side["cap_add"] and side["network_mode"] == "service:uav2"
    assert "tc qdisc" in " ".join(side["command"])
    assert "iproute2" in (ROOT / "Dockerfile").read_text()
