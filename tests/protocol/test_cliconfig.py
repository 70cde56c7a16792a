"""Command lines built from the services' typed configs (protocol.cliconfig): every config goes
model -> argv -> model unchanged through its service's own parser, the defaults need no argv, and a
bad value is argparse's one-line error with exit status 2."""

from __future__ import annotations

import argparse
import subprocess
import sys
from typing import Annotated, Literal

import pytest
from pydantic import Field

from protocol.cliconfig import Cli, CliModel, add_options, default_of, from_namespace, parse, to_argv


def _services():
    from edge import board
    from edge.config import EdgeConfig
    from protocol.messages import Box
    from services.detector import service as detector
    from services.detector.config import DetectorConfig
    from services.detector.partition import Partition
    from services.experiment import cli as experiment
    from services.experiment.config import ExperimentConfig
    from services.gateway import service as gateway
    from services.gateway.config import GatewayConfig
    from services.gcs import cli as gcs
    from services.gcs.config import GcsMissionConfig
    from services.planner import service as planner
    from services.planner.config import PlannerConfig
    from services.video import service as video
    from services.video.config import VideoConfig
    from services.web import service as web
    from services.web.config import WebConfig

    bus = dict(connect=["tcp/127.0.0.1:7447?rel=1", "udp/127.0.0.1:7448?rel=0"], multilink=True, fleet="f-1",
               keys="/k", cfg=[("transport/link/tx/lease", "3000"), ("", "{mode:'peer'}")], lease=4.5)
    return [
        (board.build_parser, [], EdgeConfig(
            uav=7, vehicle="mavlink", mavlink="udpin:0.0.0.0:14551", flight="auto", mavlink_video=5600,
            home=(-1.5, 2.0, 0.0), rate=10.0, failsafe_action="rtl", failsafe_escalate="none", battery_low=0.3,
            geofence=Box(lo=(-10, -10, 0), hi=(10, 10, 20)), speed=4.0, epoch=1.7e9, seed=3, wind="calm",
            camera="none", scenario="s.toml", frame_size=(4000, 3000), capture_link="reliable", preview_hz=0.0,
            nice=5, imagery_cache=0, mesh_uavs=6, mode="client", **bus)),
        (gateway.build_parser, [], GatewayConfig(id="g2", port=7500, period=0.5, state_ingress_hz=0.0,
                                                 no_accept_guard=True, listen=["tls/0.0.0.0:7447"], **bus)),
        (planner.build_parser, [], PlannerConfig(time_budget=3.0, anytime=True, **bus)),
        (detector.build_parser, [], DetectorConfig(method="it", workers=1, start_method="forkserver",
                                                   partition=Partition(1, 2), max_uav=12, no_recovery=True,
                                                   detect_max_mp=0.0, save_frames="out/frames", **bus)),
        (video.build_parser, [], VideoConfig(codec="mjpeg", port=6000, capture=True, uavs=3, network="n.json",
                                             **bus)),
        (web.build_parser, [], WebConfig(listen_web="0.0.0.0:8081", rate=5.0, token="t" * 20,
                                         allow_host=["a.example", "b.example"], frames="f", **bus)),
        (gcs.build_parser, [], GcsMissionConfig(scenario="s.toml", uavs=6, seed=2, speed=8.0, out="r",
                                                         quiet=True, no_record=True, web=":8080",
                                                         no_ground_truth=True, **bus)),
        (experiment.build_parser, [], ExperimentConfig(loss=(1.0, 2.5), delay=(10.0,), jitter=(0.0, 5.0),
                                                       recovery=(True, False), repeat=2, links="uav2/udp", speed=4.0,
                                                       uavs=2, seed=5, out="o", timeout=60.0, dry_run=True)),
    ]


@pytest.mark.parametrize("case", range(8))
def test_every_service_config_goes_through_its_own_command_line_unchanged(case):
    build, prefix, config = _services()[case]
    argv = to_argv(config)
    assert argv and all(a.startswith("--") for a in argv)
    back = from_namespace(type(config), build().parse_args([*prefix, *argv]))
    assert back == config, (argv, back)
    # the defaults need no argv (the edge: only its required --uav)
    required = {n: getattr(config, n) for n, f in type(config).model_fields.items() if f.is_required()}
    plain = type(config)(**required)
    assert to_argv(plain) == [f"--{n}={v}" for n, v in required.items()]
    assert from_namespace(type(config), build().parse_args([*prefix, *to_argv(plain)])) == plain


def test_the_namespace_holds_typed_values_and_the_defaults_are_the_models():
    from edge.board import build_parser
    from edge.config import FRAME_SIZE, EdgeConfig

    ns = build_parser().parse_args(["--uav", "2", "--frame-size", "800x600", "--home", "1,2,3", "-e", "tcp/a:1"])
    assert ns.frame_size == (800, 600) and ns.home == (1.0, 2.0, 3.0) and ns.connect == ["tcp/a:1"]
    assert build_parser().parse_args(["--uav", "2"]).frame_size == FRAME_SIZE == EdgeConfig(uav=2).frame_size
    assert "(default: 640x480)" in " ".join(build_parser().format_help().split())


class _Demo(CliModel):
    name: str = Field(default="x", description="a name")
    kind: Literal["a", "b"] = "a"
    n: Annotated[int, Cli(short="-n", metavar="N", group="numbers")] = Field(default=1, ge=0, le=9)
    ratio: float | None = Field(default=None, gt=0)
    tags: list[str] = []
    on: bool = False


def test_switches_choices_lists_and_one_line_errors(capsys):
    parser = add_options(argparse.ArgumentParser(prog="demo"), _Demo)
    d = from_namespace(_Demo, parser.parse_args(["--on", "--tags", "p", "--tags", "q", "-n", "3", "--kind", "b"]))
    assert d == _Demo(on=True, tags=["p", "q"], n=3, kind="b")
    assert to_argv(d) == ["--kind=b", "--n=3", "--tags=p", "--tags=q", "--on"]
    assert "a name (default: x)" in parser.format_help()
    for bad in (["-n", "10"], ["-n", "x"], ["--kind", "c"], ["--ratio", "nan"], ["--ratio", "0"], ["--nope"]):
        with pytest.raises(SystemExit) as exc:
            parse(_Demo, bad, prog="demo")
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("demo: error:") and "Traceback" not in "\n".join(err), err
    with pytest.raises(ValueError, match="n: Input should be less than or equal to 9"):
        from_namespace(_Demo, argparse.Namespace(n=12))


def test_a_switch_must_default_to_off():
    class Bad(CliModel):
        on: bool = True

    with pytest.raises(TypeError, match="defaults to off"):
        add_options(argparse.ArgumentParser(), Bad)


def test_a_bad_service_option_is_one_line_and_exit_2():
    for argv in (["edge", "--uav", "1", "--battery-low", "0.05"], ["edge", "--uav", "1", "--frame-size", "1x1"],
                 ["gateway", "--fleet", "a/b"], ["detector", "--partition", "3/2"], ["planner", "--lease-s", "-1"],
                 ["experiment", "--links", "uav9"], ["web", "--web", "nowhere"]):
        p = subprocess.run([sys.executable, "-m", "services.cli", *argv], capture_output=True, text=True, timeout=60)
        lines = p.stderr.strip().splitlines()
        assert p.returncode == 2 and "error:" in lines[-1] and "Traceback" not in p.stderr, (argv, p.stderr)


def test_the_launcher_imports_no_opencv():
    """``skynet up`` builds the edges' command lines from their config without the camera's libraries."""
    code = "import sys, services.orchestration.launcher; print(sorted(m for m in sys.modules if m.split('.')[0] == 'cv2'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


class _Exclusive(CliModel):
    keys: Annotated[str | None, Cli(exclusive="trust")] = None
    insecure: Annotated[bool, Cli(exclusive="trust")] = False
    other: int = 0


def test_exclusive_options_are_one_argparse_group_and_the_model_refuses_them_together(capsys):
    parser = add_options(argparse.ArgumentParser(prog="demo"), _Exclusive)
    assert "[--keys KEYS | --insecure]" in parser.format_usage()
    assert "(not with --insecure)" in parser.format_help() and "(not with --keys)" in parser.format_help()
    with pytest.raises(SystemExit) as exc:
        parse(_Exclusive, ["--keys", "k", "--insecure"], prog="demo")
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == \
        "demo: error: argument --insecure: not allowed with argument --keys"
    assert parse(_Exclusive, ["--insecure", "--other", "1"]) == _Exclusive(insecure=True, other=1)
    with pytest.raises(ValueError, match="--keys: not allowed with --insecure"):
        _Exclusive(keys="k", insecure=True)


@pytest.mark.parametrize("argv", [["edge", "--uav", "1", "--keys", "k", "--insecure"],
                                  ["up", "--keys", "k", "--insecure", "--dry-run"],
                                  ["mission", "--insecure", "--keys", "k", "--dry-run"]])
def test_keys_and_insecure_are_mutually_exclusive_on_every_command_having_both(argv):
    p = subprocess.run([sys.executable, "-m", "services.cli", *argv], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and p.stderr.strip().splitlines()[-1].endswith("not allowed with argument --keys") \
        or p.stderr.strip().splitlines()[-1].endswith("not allowed with argument --insecure"), p.stderr


def test_show_defaults_names_the_default_of_a_hand_written_parser_and_its_subcommands():
    from protocol.cliconfig import show_defaults

    parser = argparse.ArgumentParser(prog="demo")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="a folder")
    parser.add_argument("--speed", type=float, default=1.0, help="factor (default: real time)")
    sub = parser.add_subparsers(dest="cmd").add_parser("run")
    sub.add_argument("--loss-pct", default="5%", help="loss")
    show_defaults(parser)
    text = parser.format_help()
    assert "(default: 0)" in text and "a folder\n" in text and "(default: real time)" in text
    assert text.count("default") == 2  # --out has none; --speed's own wording is kept
    assert "loss (default: 5%)" in sub.format_help()


def test_gcs_is_the_mission_and_gcs_mission_is_the_same_command():
    from services.gcs import cli as gcs
    from services.gcs.config import GcsMissionConfig

    parser = gcs.build_parser()
    assert from_namespace(GcsMissionConfig, parser.parse_args(["--uavs", "6"])).uavs == 6
    for argv in (["gcs", "--scenario", "/nonexistent.toml"], ["gcs", "mission", "--scenario", "/nonexistent.toml"]):
        p = subprocess.run([sys.executable, "-m", "services.cli", *argv], capture_output=True, text=True, timeout=60)
        assert p.returncode == 2 and "cannot read scenario file" in p.stderr.strip().splitlines()[-1], p.stderr


def test_default_of_is_the_models_own_default_factories_called():
    from pydantic import BaseModel, Field

    class Opts(BaseModel):
        speed: float = 4.0
        hosts: list[str] = Field(default_factory=lambda: ["a"])

    assert default_of(Opts, "speed") == 4.0 and default_of(Opts, "hosts") == ["a"]
    assert default_of(Opts, "hosts") is not default_of(Opts, "hosts")  # a fresh list each time
