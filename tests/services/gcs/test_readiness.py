"""The fleet's readiness policy before takeoff (services/gcs/readiness.py): pure logic on real states."""

import pydantic
import pytest

from protocol import codec
from protocol.messages import AutopilotReadiness, Mode, VehicleState
from services.gcs.readiness import not_ready, refusal


def state(uav: int, autopilot: AutopilotReadiness | None) -> VehicleState:
    return VehicleState(uav=uav, seq=1, t=0.0, stamp=1.0, pos=(0, 0, 0), vel=(0, 0, 0), att=(0, 0, 0),
                        rates=(0, 0, 0), mode=Mode.IDLE, autopilot=autopilot)


def test_built_in_vehicles_and_ready_autopilots_pass_the_others_say_why():
    ok = AutopilotReadiness(ready=True, heartbeat=True, status="standby", home=True, position=True, armable=True)
    waiting = AutopilotReadiness(ready=False, heartbeat=True, status="standby", home=False,
                                 reason="no home position yet; the autopilot says: PreArm: AHRS: waiting for home")
    states = {1: state(1, None), 2: state(2, ok), 3: state(3, waiting)}
    assert not_ready(states, (1, 2)) == {}
    got = not_ready(states, (1, 2, 3, 4))
    assert set(got) == {3, 4} and "waiting for home" in got[3] and "no state" in got[4]
    text = refusal(got, 60.4)
    assert text.startswith("refused before takeoff: autopilot not ready after 60 s")
    assert "UAV 3: no home position yet" in text and "UAV 4:" in text and "\n" not in text


def test_the_readiness_travels_in_the_state_and_hostile_values_are_refused():
    r = AutopilotReadiness(ready=False, heartbeat=True, status="boot", reason="x" * 256)
    msg = state(1, r)
    assert codec.decode(codec.encode(msg)) == msg

    with pytest.raises(pydantic.ValidationError):
        AutopilotReadiness(ready=True, heartbeat=True, reason="x" * 257)
    with pytest.raises(pydantic.ValidationError):
        AutopilotReadiness(ready=True, heartbeat=True, status="s" * 33)
    with pytest.raises(pydantic.ValidationError):
        AutopilotReadiness.model_validate({"ready": True, "heartbeat": True, "extra": 1})


HOSTILE = "\x1b[2J\x1b]0;pwned\x07\r\n12:00:00 gcs INFO mission succeeded <img src=x onerror=alert(1)> | `x` \u202e"


def test_a_hostile_refusal_reason_is_escaped_in_the_log_line_and_in_report_md():
    """An autopilot's reason is another node's text: its control characters and HTML stay inert."""
    import logging

    from protocol.textsafe import SafeFormatter
    from services.gcs.figures import summarise
    from services.gcs.markdown import markdown
    from services.recording.record import MissionRecord

    waiting = not_ready({1: state(1, AutopilotReadiness(ready=False, heartbeat=True, reason=HOSTILE))}, [1])
    line = refusal(waiting, 120.0)
    assert line.isprintable() and "\\x1b[2J" in line and "\\u202e" in line and "\n" not in line
    rec = logging.LogRecord("skynet.gcs", logging.ERROR, __file__, 1, "mission failed: %s", (line,), None)
    logged = SafeFormatter("%(levelname)s %(message)s").format(rec)
    assert logged.isprintable() and logged.startswith("ERROR mission failed: refused before takeoff")
    record = MissionRecord(fleet="f", speed=1.0, started=0.0, failures=[line])
    md = markdown(record, summarise(record))  # report.md's text (services.gcs.report.write_report)
    outcome = next(ln for ln in md.splitlines() if ln.startswith("Outcome:"))
    assert "refused before takeoff" in outcome and "\x1b" not in md and "\u202e" not in md and "\x07" not in md
    assert "<img" not in md and "&lt;img src=x onerror=alert(1)&gt;" in outcome and "\\|" in outcome
