"""The running network's description (services.attach): written and removed by its launcher,
read by the tools, every way it cannot be used said in one sentence. Real files, no bus (the processes are
in test_compose.py)."""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.bus import add_bus_args
from services import attach
from services import keys as pki

EPS = ["tls/127.0.0.1:30001?rel=1", "tls/127.0.0.1:30002?rel=0"]


@pytest.fixture(scope="module")
def keyset(tmp_path_factory) -> Path:
    return pki.init(tmp_path_factory.mktemp("keys") / "dev", 1)


def _args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_bus_args(p, mode="client")
    attach.add_network_arg(p)
    return p.parse_args(argv)


def _written(tmp_path: Path, keyset: Path, **changes) -> Path:
    desc = {**attach.describe("blue", EPS, keyset, tls=True), **changes}
    return attach.write(tmp_path / ".skynet" / "network.json", desc)


def test_the_description_fills_the_tools_bus_options(tmp_path, keyset):
    path = _written(tmp_path, keyset)
    desc = json.loads(path.read_text())
    assert desc["fleet"] == "blue" and desc["replay_fleet"] == "blue-replay" and desc["endpoints"] == EPS
    assert desc["ca_sha256"] == attach.ca_fingerprint(keyset) and len(desc["ca_sha256"]) == 64
    assert not any("PRIVATE" in str(v) for v in desc.values())  # a path and a fingerprint, never a key
    args = _args(["--network", str(path)])
    assert attach.attach(args, "web", ["--network", str(path)]) is not None
    assert args.connect == EPS and args.multilink and args.mode == "client"
    assert args.fleet == "blue" and args.keys == str(keyset.resolve())
    # a replay page: the replay fleet is the network's too
    args = _args(["--network", str(path), "--fleet", "blue-replay"])
    attach.attach(args, "web", ["--network", str(path), "--fleet", "blue-replay"])
    assert args.fleet == "blue-replay"


def test_endpoints_given_by_hand_win(tmp_path, keyset):
    args = _args(["-e", "tcp/127.0.0.1:7447"])
    assert attach.attach(args, "video", ["-e", "tcp/127.0.0.1:7447"]) is None
    assert args.connect == ["tcp/127.0.0.1:7447"] and args.keys is None


@pytest.mark.parametrize("case,words", [
    ("missing", "no network running here"),
    ("garbage", "is not a network description"),
    ("no-endpoints", "no endpoints"),
    ("bad-fleet", "fleet must match"),
    ("huge", "over 65536 bytes"),
    ("ended", "has ended"),
    ("fleet", "carries fleet blue"),
    ("other-keys", "not the running network's key set"),
    ("no-identity", "has no identity for video"),
])
def test_what_cannot_attach_is_said_in_one_line(tmp_path, keyset, case, words):
    path = tmp_path / "net.json"
    argv = ["--network", str(path)]
    if case == "garbage":
        path.write_text("{not json")
    elif case == "no-endpoints":
        _written(tmp_path, keyset, endpoints=[]).rename(path)
    elif case == "bad-fleet":
        _written(tmp_path, keyset, fleet="a/b").rename(path)
    elif case == "huge":
        path.write_text(json.dumps({"pad": "x" * 70_000}))
    elif case == "ended":
        dead = subprocess.Popen([sys.executable, "-c", "pass"])
        dead.wait()
        _written(tmp_path, keyset, pid=dead.pid).rename(path)
    elif case != "missing":
        _written(tmp_path, keyset).rename(path)
    if case == "fleet":
        argv += ["--fleet", "red"]
    elif case == "other-keys":
        argv += ["--keys", str(pki.init(tmp_path / "other", 1))]
    elif case == "no-identity":
        own = tmp_path / "own"
        shutil.copytree(keyset, own)
        shutil.rmtree(own / "video")
        argv += ["--keys", str(own)]
    with pytest.raises(attach.AttachError) as err:
        attach.attach(_args(argv), "video", argv)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_only_the_launcher_that_wrote_it_removes_it(tmp_path, keyset):
    path = _written(tmp_path, keyset)
    assert not attach.remove(path, pid=1)  # another launcher's
    assert path.exists()
    assert attach.remove(path)
    assert not path.exists() and not path.parent.exists()  # the empty .skynet folder goes too


def test_zenohs_refusals_become_sentences():
    args = _args([])
    assert "start a network with `skynet up`" in attach.explain_open_error(
        RuntimeError("No peer specified and multicast scouting deactivated!"), args, None, "web")
    args = _args(["-e", EPS[0], "--keys", "/k"])
    text = attach.explain_open_error(RuntimeError(f"Unable to connect to any of [{EPS[0]}]! Timeout!"), args, None,
                                     "replay")
    assert text.startswith("no gateway answered at tls/") and "replay's identity in /k" in text
    assert "Timeout!" not in text


def test_a_folder_the_description_cannot_go_to_is_said_not_fatal(tmp_path, caplog):
    from services.orchestration.launcher import Network, parse

    blocker = tmp_path / "file"
    blocker.write_text("a file where the .skynet folder would go")
    args = parse("up", ["--insecure", "--network", str(blocker / "network.json")])
    net = Network(args)
    try:
        assert net.describe() is None
        assert "could not describe the network" in caplog.text and "-e tcp/" in caplog.text
    finally:
        net.stop()
