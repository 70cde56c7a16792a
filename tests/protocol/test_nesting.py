"""Deep nesting in TOML, JSON and msgpack input is a one-line error or a counted rejection, never a
RecursionError traceback: the scenario through ``skynet plan mission`` and ``skynet mission`` in their own
processes, the wire codec, and JSON read from files (the mission log's case is in
tests/services/gcs/test_hostile_input.py)."""

from __future__ import annotations

import subprocess
import sys

import msgpack
import pytest

from protocol import codec
from protocol.scenario import ScenarioError, load_scenario
from tests.conftest import ROOT

DEPTH = 100_000


@pytest.fixture(scope="module")
def nested_toml(tmp_path_factory):
    path = tmp_path_factory.mktemp("nested") / "nested.toml"
    path.write_text("a = " + "[" * DEPTH + "]" * DEPTH + "\n")
    return path


def _one_line_error(proc: subprocess.CompletedProcess, name: str) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr and "RecursionError" not in proc.stderr, proc.stderr[-2000:]
    lines = [ln for ln in proc.stderr.splitlines() if f"skynet {name}" in ln and "nested too deeply" in ln]
    assert len(lines) == 1, proc.stderr[-2000:]
    return lines[0]


def test_load_scenario_refuses_deep_nesting(nested_toml, tmp_path):
    with pytest.raises(ScenarioError, match="nested too deeply"):
        load_scenario(nested_toml)
    table = tmp_path / "tables.toml"
    table.write_text("a = " + "{b = " * 5000 + "1" + "}" * 5000 + "\n")  # inline tables recurse the same way
    with pytest.raises(ScenarioError, match="nested too deeply"):
        load_scenario(table)


@pytest.mark.parametrize("argv", [["plan", "mission"], ["mission", "--out", "{tmp}/report"]],
                         ids=["skynet plan mission", "skynet mission"])
def test_skynet_commands_refuse_a_nested_scenario_in_one_line(nested_toml, tmp_path, argv):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    proc = subprocess.run([sys.executable, "-m", "services.cli", *argv, "--scenario", str(nested_toml)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    line = _one_line_error(proc, argv[0])
    assert str(nested_toml) in line
    assert len(proc.stderr.splitlines()) < 10, proc.stderr[-2000:]


def test_the_wire_codec_refuses_deep_msgpack_as_bad_bytes():
    deep = b"\x93\x01\xa5event" + b"\x81\xa4data" + b"\x91" * DEPTH + b"\xc0"
    with pytest.raises(codec.CodecError) as exc:
        codec.decode(deep)
    assert exc.value.kind == "bad-bytes" and "nested too deeply" in str(exc.value)
    within = [1, "event", {"source": "uav/1", "stamp": 1.0, "kind": "failsafe", "data": {"x": [[[[[[1]]]]]]}}]
    with pytest.raises(codec.CodecError) as exc:  # shallow enough to unpack: the schema refuses it
        codec.decode(msgpack.packb(within))
    assert exc.value.kind == "invalid"


def test_json_from_outside_is_a_value_error_when_nested_too_deeply():
    with pytest.raises(ValueError, match="nested too deeply"):
        codec.loads_json("[" * DEPTH + "]" * DEPTH)
    assert codec.loads_json('{"a": [[1]]}') == {"a": [[1]]}
    from services.planner.export import parse_qgc_plan

    with pytest.raises(ValueError, match="nested too deeply"):
        parse_qgc_plan('{"fileType": ' + "[" * DEPTH + "]" * DEPTH + "}")
