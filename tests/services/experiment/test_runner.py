"""The experiment runner with real processes: a stuck run is stopped and recorded, never hangs the experiment;
and one tiny real experiment end to end (the one slow test here: one whole mission, ~35 s)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from services.experiment.cli import main
from services.experiment.grid import Cell, Run
from services.experiment.runner import descendants, run_mission
from tests.conftest import wait_until

STUCK = textwrap.dedent("""
    import signal, subprocess, sys, time
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    child = subprocess.Popen([sys.executable, "-c",
        "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); time.sleep(600)"],
        start_new_session=True)  # like the launcher's services: out of our process group
    open(sys.argv[1], "w").write(str(child.pid))
    time.sleep(600)
""")


def _gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return True
    return state in ("Z", "X")  # killed, not yet reaped by init


def test_a_stuck_run_and_what_it_started_are_killed_and_recorded_as_hung(tmp_path):
    pid_file = tmp_path / "child.pid"
    run = Run(Cell(40, 200, 0), 0, 0)
    t0 = time.monotonic()
    res = run_mission(run, [sys.executable, "-c", STUCK, str(pid_file)], tmp_path / "run", timeout_s=2.0,
                      grace_s=1.0)
    assert time.monotonic() - t0 < 30
    assert res.status == "hung" and res.exit is not None and res.metrics["success"] == 0.0
    child = int(pid_file.read_text())
    assert wait_until(lambda: _gone(child), 5)  # SIGKILL is delivered, not awaited


def test_a_run_that_ends_without_report_is_counted_not_fatal(tmp_path):
    res = run_mission(Run(Cell(0, 0, 0), 0, 0), [sys.executable, "-c", "print('boom'); raise SystemExit(3)"],
                      tmp_path / "run", timeout_s=20)
    assert (res.status, res.exit) == ("no-report", 3)
    assert "boom" in (tmp_path / "run" / "mission.log").read_text()


def test_descendants_lists_children_and_grandchildren():
    p = subprocess.Popen([sys.executable, "-c", textwrap.dedent("""
        import subprocess, sys, time
        subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
        print("ready", flush=True); time.sleep(30)""")], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "ready"
        family = descendants(p.pid)
        assert len(family) == 1 and family[0][1] is not None
        assert descendants(family[0][0]) == []
    finally:
        for pid, _ in descendants(p.pid):
            subprocess.run(["kill", str(pid)], check=False)
        p.kill()
        p.wait()


def test_bad_options_exit_2(capsys):
    for argv in (["--loss-pct", "5,abc"], ["--delay-ms", "-5"], ["--recovery", "sometimes"], ["--links", "uav9"],
                 ["--repeat", "0"], ["--timeout-s", "0"], ["--method", "nope"], ["--vehicle", "plane"],
                 ["--flight", "loiter"], ["--flight", "auto"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("skynet experiment: error:") and "Traceback" not in "\n".join(err), err


def test_dry_run_prints_one_command_per_run(capsys):
    assert main(["--dry-run", "--loss-pct", "0,20", "--delay-ms", "200", "--recovery", "on,off", "--repeat", "2",
                 "--out", "/tmp/nowhere"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 8 and sum("--no-recovery" in line for line in lines) == 4
    assert all("'all/udp=after 2s delay 200ms" in line for line in lines)
    assert not any("--insecure" in line for line in lines)  # the default secure mode
    assert main(["--dry-run", "--insecure", "--loss-pct", "20", "--delay-ms", "0", "--out", "/tmp/nowhere"]) == 0
    assert capsys.readouterr().out.rstrip().endswith("--insecure")  # the paper's UDP class, datagram loss
    assert not Path("/tmp/nowhere").exists()


def test_every_run_flies_the_method_and_vehicle_asked_for(capsys):
    """The grid varies the links; the detector's method and the vehicle are the user's, the same in every run."""
    assert main(["--dry-run", "--loss-pct", "0,20", "--delay-ms", "0", "--out", "/tmp/nowhere"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2 and all("--method it+r --vehicle sim" in line and "--flight" not in line for line in lines)
    assert main(["--dry-run", "--loss-pct", "5", "--delay-ms", "0", "--method", "learned", "--vehicle", "mavlink",
                 "--flight", "auto", "--out", "/tmp/nowhere"]) == 0
    line = capsys.readouterr().out.strip()
    assert "--method learned --vehicle mavlink --flight auto" in line and "'all/udp=after 2s loss 5%'" in line


@pytest.mark.mission
def test_one_cell_experiment_end_to_end(tmp_path, capsys):
    """Slow (one whole mission, ~35 s wall at the default speed 6): the real thing, one tiny cell, with a detector
    method of the user's choice (the paper's IT) reaching the run's detector."""
    out = tmp_path / "exp"
    code = main(["--loss-pct", "10", "--delay-ms", "20", "--repeat", "1", "--seed", "3", "--method", "it",
                 "--out", str(out), "--timeout-s", "240"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    for name in ("results.json", "results.md", "coverage.png", "imagery.png", "telemetry.png", "commands.png"):
        assert (out / name).stat().st_size > 0, name
    doc = json.loads((out / "results.json").read_text())
    assert doc["experiment"]["runs_done"] == 1 and len(doc["cells"]) == 1
    run = doc["runs"][0]
    assert run["status"] == "ok" and "all/udp=after 2s delay 20ms loss 10%" in run["command"]
    assert (Path(run["out"]) / "report.json").exists()
    cmd = run["command"]
    assert doc["experiment"]["method"] == "it" and cmd[cmd.index("--method") + 1] == "it"
    assert ", method it, " in (Path(run["out"]) / "services.log").read_text()
    m = doc["cells"][0]["metrics"]
    # sane numbers: with recovery on every capture point is imaged, every command acknowledged. (Mission
    # success also needs every UAV within 2 m of its goal, a flight verdict this test does not judge.)
    assert m["success"]["mean"] in (0.0, 1.0) and m["coverage"]["mean"] == 1.0
    assert m["cmd_ack_ratio"]["mean"] == 1.0 and m["cmd_ack_p95_ms"]["mean"] > 0
    assert 0.5 < m["telemetry_ratio"]["mean"] < 1.0  # 10 % loss on two hops, for the ground station's states
    assert m["telemetry_age_p95_ms"]["mean"] >= 20  # the delay is there
    assert m["img_delivered"]["mean"] == m["captures_planned"]["mean"] and m["img_missing"]["mean"] == 0
    assert m["img_lost"]["mean"] == 0
    assert m["defects_found"]["mean"] <= m["defects_planted"]["mean"]
    table = (out / "results.md").read_text()
    row = f"| 10 | 20 | 0 | on | {int(m['success']['mean'])}/1 | 100 | {m['img_delivered']['mean']:.0f} | 0 | 0 | 0 |"
    assert row in table and row in printed
    # what loss means in the mode flown: the default secure mode turns it into retransmission delay
    assert "Secure mode (the default)" in table and "retransmission delay" in printed
    assert "detector method `it`, vehicle `sim`;" in table
