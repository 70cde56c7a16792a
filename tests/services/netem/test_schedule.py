"""Tests of services.netem.schedule: the command grammar and schedule files (pure)."""

from __future__ import annotations

import pytest

from services.netem.model import Impairment
from services.netem.schedule import Command, ScheduleError, Step, load_schedule, parse_command, parse_schedule

EXAMPLE = """\
# the link gets worse, drops out, and recovers
at 0s    "delay 50ms loss 2%"
at 10s   "delay 200ms jitter 20ms loss 20%"   # worse
at 25s   cut 5s

at 40s   clear
at 500ms set up loss 1%
at 25s   restore
at 30s   cut
"""


def test_the_example_parses_into_sorted_validated_steps():
    steps = parse_schedule(EXAMPLE)
    assert [(s.at_s, s.command.action, s.line) for s in steps] == [
        (0.0, "set", 2), (0.5, "set", 7), (10.0, "set", 3), (25.0, "cut", 4), (25.0, "restore", 8),
        (30.0, "cut", 9), (40.0, "clear", 6)]  # same time: file order
    assert steps[0].command.impairment == Impairment.parse("delay 50ms loss 2%")
    assert steps[0].command.direction == "both" and steps[1].command.direction == "up"
    assert steps[3].command.duration_s == 5.0 and steps[5].command.duration_s is None


def test_commands_and_their_text_round_trip():
    for text in ('set "delay 50ms loss 2%"', "set down delay 5ms", "set none", 'set ""', "cut", "cut 1.5s",
                 "restore", "clear", "stats", "delay 10ms jitter 2ms", "CUT 250ms"):
        cmd = parse_command(text)
        assert parse_command(cmd.to_text()) == cmd
    assert parse_command("set none") == parse_command('set ""') == Command(action="set", impairment=Impairment())
    assert parse_command("delay 10ms").impairment.delay_ms == 10.0
    assert parse_command("cut 250ms").duration_s == 0.25
    step = parse_schedule("at 1.5s cut 2s")[0]
    assert parse_schedule(step.to_text()) == [step.model_copy(update={"line": 1})]


@pytest.mark.parametrize("text, words", [
    ("", "empty"), ("cutt 5s", "'cutt'"), ("cut 5", "'5'"), ("cut 0s", "> 0"), ("cut 1s 2s", "one duration"),
    ("restore now", "no arguments"), ('set "loss 2"', "'2'"), ("set up", "needs an impairment"), ("set", "needs an impairment"), ('set "delay 5ms', "quotation"),
])
def test_bad_commands_are_one_line_value_errors(text, words):
    with pytest.raises(ValueError) as e:
        parse_command(text)
    assert words in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("line, words", [
    ("at 5 cut", "bad time '5'"), ("cut 5s", "expected 'at TIME COMMAND'"), ("at 5s", "expected 'at TIME"),
    ("at 1s stats", "control-channel"), ('at 1s "loss 2"', "'2'"), ("at -1s clear", "bad time"),
    ("at 1s cut 5s # ok\nat 2s bogus", "'bogus'"),
])
def test_schedule_errors_name_the_file_and_line(line, words):
    text = "# header\n\n" + line
    bad_line = text.count("\n") + 1
    with pytest.raises(ScheduleError) as e:
        parse_schedule(text, "sched.txt")
    assert str(e.value).startswith(f"sched.txt:{bad_line}: ") and words in str(e.value)
    assert e.value.line == bad_line and isinstance(e.value, ValueError)


def test_load_schedule_reads_a_file_and_reports_unreadable_ones(tmp_path):
    path = tmp_path / "s.txt"
    path.write_text(EXAMPLE)
    assert load_schedule(path) == parse_schedule(EXAMPLE)
    with pytest.raises(ScheduleError, match="missing.txt:0: cannot read"):
        load_schedule(tmp_path / "missing.txt")


def test_commands_and_steps_are_validated_models():
    with pytest.raises(ValueError):
        Command(action="cut", impairment=Impairment())
    with pytest.raises(ValueError):
        Command(action="set")
    with pytest.raises(ValueError):
        Command(action="restore", direction="up")
    with pytest.raises(ValueError):
        Step(at_s=-1.0, command=Command(action="clear"))
