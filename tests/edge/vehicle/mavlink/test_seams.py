"""The MAVLink driver's seams without a link: the handler table, the command awaiter, the phase rules,
the dialect and the AUTO flight's one worker. Real pymavlink messages, encoded and decoded."""

from __future__ import annotations

import math
import threading
import time
from types import SimpleNamespace

import pytest

pytest.importorskip("pymavlink", reason="the MAVLink driver needs the 'mavlink' extra")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.vehicle.apm.modes import CopterMode  # noqa: E402
from edge.vehicle.mavlink import ARDUCOPTER, CommandRefused, MavlinkParams, Phase, VehicleLinkError  # noqa: E402
from edge.vehicle.mavlink.auto import AutoFlight  # noqa: E402
from edge.vehicle.mavlink.commands import CommandAwaiter  # noqa: E402
from edge.vehicle.mavlink.handlers import HANDLERS, Telemetry, dispatch, stream_requests  # noqa: E402
from edge.vehicle.mavlink.phase import overrule  # noqa: E402
from protocol.messages import Mode  # noqa: E402

HOME = (10.0, -5.0, 2.0)


def wire(msg, src: int = 1, comp: int = 1):
    """``msg`` as the driver receives it: packed by system ``src`` and decoded."""
    return M.MAVLink(None).decode(bytearray(msg.pack(M.MAVLink(None, srcSystem=src, srcComponent=comp))))


def heartbeat(mode: int = CopterMode.GUIDED, armed: bool = True, src: int = 1, autopilot=M.MAV_AUTOPILOT_ARDUPILOTMEGA):
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (M.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return wire(M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, autopilot, base, int(mode), M.MAV_STATE_ACTIVE, 3),
                src)


def ack(command: int, result: int, src: int = 1):
    return wire(M.MAVLink_command_ack_message(command, result, 0, 0, 255, 191), src)


def heard() -> Telemetry:
    t = Telemetry(1, HOME, our_system=255)
    dispatch(t, heartbeat(), 0.0)
    return t


# ---------------------------------------------------------------------------------- handler table
def test_the_handler_table_covers_what_the_driver_reads():
    assert {"HEARTBEAT", "LOCAL_POSITION_NED", "ATTITUDE", "SYS_STATUS", "STATUSTEXT", "HOME_POSITION",
            "EKF_STATUS_REPORT", "MISSION_ITEM_REACHED", "MISSION_CURRENT", "PARAM_VALUE", "PARAM_ERROR", "MISSION_REQUEST_INT",
            "MISSION_REQUEST", "MISSION_ACK", "COMMAND_ACK"} == set(HANDLERS)


def test_handlers_fill_the_telemetry_from_the_target_system_only():
    t = Telemetry(1, HOME, our_system=255)
    dispatch(t, heartbeat(src=7, autopilot=M.MAV_AUTOPILOT_INVALID), 0.0)  # a GCS: not a vehicle
    assert t.sysid is None and t.hb is None
    dispatch(t, heartbeat(CopterMode.LOITER, armed=True, src=3), 1.0)
    assert t.sysid == 3 and t.hb.custom_mode == CopterMode.LOITER and t.hb.armed and t.autopilot == 3
    pos = M.MAVLink_local_position_ned_message(0, 1.0, 2.0, -3.0, 0.5, 0.0, 0.0)
    dispatch(t, wire(pos, src=4), 1.0)  # another vehicle
    assert t.pos == HOME
    dispatch(t, wire(pos, src=3), 1.0)
    assert t.pos == (HOME[0] + 2.0, HOME[1] + 1.0, HOME[2] + 3.0) and t.vel == (0.0, 0.5, 0.0)
    bad = M.MAVLink_local_position_ned_message(0, math.nan, 2.0, -3.0, 0.0, 0.0, 0.0)
    dispatch(t, wire(bad, src=3), 1.0)
    assert t.errors == 1 and t.pos == (HOME[0] + 2.0, HOME[1] + 1.0, HOME[2] + 3.0)  # counted, kept
    dispatch(t, wire(M.MAVLink_statustext_message(M.MAV_SEVERITY_CRITICAL, b"PreArm: Need Position Estimate"),
                     src=3), 2.0)
    assert t.not_ready_text == "PreArm: Need Position Estimate"
    dispatch(t, wire(M.MAVLink_command_ack_message(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAV_RESULT_UNSUPPORTED,
                                                   0, 0, 255, 191), src=3), 2.0)
    assert t.legacy_streams  # asks with REQUEST_DATA_STREAM from now on
    asks = stream_requests(t, 10.0)
    assert {m.get_type() for m in asks} == {"REQUEST_DATA_STREAM", "COMMAND_LONG"}  # HOME_POSITION: GET_HOME


# ---------------------------------------------------------------------------------- command awaiter
class Autopilot:
    """Answers each attempt of the awaiter as told: ``script[attempt]`` is a list of acks (or nothing)."""

    def __init__(self, tel: Telemetry, script: dict[int, list]):
        self.tel, self.script, self.sent = tel, script, []

    def __call__(self, command, confirmation, params, frame):
        self.sent.append((command, confirmation, params, frame))
        for msg in self.script.get(confirmation, []):
            dispatch(self.tel, msg, time.monotonic())


def test_the_awaiter_matches_the_ack_of_its_own_command():
    t = heard()
    ap = Autopilot(t, {0: [ack(M.MAV_CMD_NAV_LAND, M.MAV_RESULT_DENIED), ack(M.MAV_CMD_NAV_TAKEOFF,
                                                                            M.MAV_RESULT_ACCEPTED)]})
    rx = CommandAwaiter(t, ap, 0.2, 1).call(M.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, 5.0), "take off")
    assert rx == t.rx and len(ap.sent) == 1 and ap.sent[0][2][6] == 5.0 and ap.sent[0][3] is None


def test_the_awaiter_retries_with_the_confirmation_counted_then_gives_up():
    t = heard()
    ap = Autopilot(t, {1: [ack(M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_RESULT_ACCEPTED)]})  # the first is lost
    CommandAwaiter(t, ap, 0.05, 2).call(M.MAV_CMD_COMPONENT_ARM_DISARM, (1,), "arm")
    assert [s[1] for s in ap.sent] == [0, 1]
    silent = Autopilot(t, {})
    with pytest.raises(VehicleLinkError, match="no COMMAND_ACK to MAV_CMD_NAV_LAND within 0.05 s x 3 attempts") as e:
        CommandAwaiter(t, silent, 0.05, 2).call(M.MAV_CMD_NAV_LAND, (), "land")
    assert not isinstance(e.value, CommandRefused) and len(silent.sent) == 3


def test_in_progress_keeps_the_awaiter_waiting():
    t = heard()

    def send(command, confirmation, params, frame):
        def later():
            dispatch(t, ack(command, M.MAV_RESULT_IN_PROGRESS), 0.0)
            threading.Timer(0.3, dispatch, (t, ack(command, M.MAV_RESULT_ACCEPTED), 0.0)).start()
        threading.Timer(0.3, later).start()

    CommandAwaiter(t, send, 0.5, 0).call(M.MAV_CMD_NAV_TAKEOFF, (), "take off")  # 0.6 s in all, 0.5 s timeout


def test_a_refusal_is_a_command_refused_carrying_the_mav_result_and_the_autopilots_words():
    t = heard()
    text = wire(M.MAVLink_statustext_message(M.MAV_SEVERITY_CRITICAL, b"Arm: Throttle too high"))
    ap = Autopilot(t, {0: [text, ack(M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_RESULT_FAILED)]})
    with pytest.raises(CommandRefused) as e:
        CommandAwaiter(t, ap, 0.2, 3).call(M.MAV_CMD_COMPONENT_ARM_DISARM, (1,), "arm")
    assert e.value.result == M.MAV_RESULT_FAILED and e.value.command == M.MAV_CMD_COMPONENT_ARM_DISARM
    assert isinstance(e.value, VehicleLinkError) and isinstance(e.value, ValueError)  # callers still catch it
    assert str(e.value) == ("arm refused by the autopilot: MAV_RESULT_FAILED to MAV_CMD_COMPONENT_ARM_DISARM "
                            "(Arm: Throttle too high)")
    assert len(ap.sent) == 1  # a refusal is an answer: not retried


def test_a_command_int_carries_its_frame():
    t = heard()
    ap = Autopilot(t, {0: [ack(M.MAV_CMD_DO_REPOSITION, M.MAV_RESULT_ACCEPTED)]})
    CommandAwaiter(t, ap, 0.2, 0).call(M.MAV_CMD_DO_REPOSITION, (-1, 1, 0, math.nan, 1e7, 2e7, 10),
                                       "reposition", frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
    assert ap.sent[0][3] == M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


# ---------------------------------------------------------------------------------- phase
@pytest.mark.parametrize("phase, armed, expected, guided, after, pause, noticed", [
    (Phase.IDLE, False, False, False, Phase.IDLE, False, False),
    (Phase.MISSION, False, False, False, Phase.LANDED, True, False),  # disarmed in flight: landed
    (Phase.IDLE, True, False, True, Phase.EXTERNAL, False, False),  # armed by someone else
    (Phase.EXTERNAL, True, False, True, Phase.HOLD, False, False),  # back in GUIDED: hold there
    (Phase.EXTERNAL, True, False, False, Phase.EXTERNAL, False, False),
    (Phase.MISSION, True, True, True, Phase.MISSION, False, False),  # the autopilot agrees
    (Phase.AUTO, True, False, True, Phase.HOLD, True, True),  # AUTO left for GUIDED by someone else
    (Phase.MISSION, True, False, False, Phase.EXTERNAL, True, True),  # the pilot's LOITER/STABILIZE
])
def test_a_newer_heartbeat_overrules_the_phase(phase, armed, expected, guided, after, pause, noticed):
    assert tuple(overrule(phase, armed=armed, expected=expected, guided=guided)) == (after, pause, noticed)


def test_phase_modes_and_the_arducopter_dialect():
    assert [p.mode for p in Phase] == [Mode.IDLE, Mode.LANDED, Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.MISSION,
                                       Mode.LAND, Mode.RTL, None]
    assert ARDUCOPTER.phase_mode(Phase.AUTO) == CopterMode.AUTO and ARDUCOPTER.phase_mode(Phase.HOLD) == 4
    assert ARDUCOPTER.board_mode(CopterMode.STABILIZE) == Mode.PILOT and ARDUCOPTER.board_mode(6) == Mode.RTL
    assert ARDUCOPTER.set_mode_params(CopterMode.GUIDED) == (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)
    assert ARDUCOPTER.param_name("wp_speed", "4.7") == "WP_SPD" and ARDUCOPTER.to_raw("wp_speed", 2, "4.6") == 200


# ---------------------------------------------------------------------------------- AUTO's one worker
class FakeDriver:
    """What :class:`AutoFlight` uses of the driver; ``set_mode`` records the thread it ran on."""

    def __init__(self, refuse: bool = False):
        self.uav, self.dialect, self.params = 1, ARDUCOPTER, MavlinkParams(flight="auto")
        self.tel = Telemetry(1, HOME, 255)
        self.commands = SimpleNamespace(lock=threading.RLock())
        self.phase = Phase.MISSION
        self.threads: list[threading.Thread] = []
        self.gate = threading.Event()
        self.gate.set()
        self.refuse = refuse

    def command(self, command, params, what):
        self.threads.append(threading.current_thread())

    def set_mode(self, mode):
        self.gate.wait(5.0)
        self.threads.append(threading.current_thread())
        if self.refuse:
            raise CommandRefused(f"set mode {mode}", M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_TEMPORARILY_REJECTED)


def settle(auto: AutoFlight) -> None:
    auto._worker.submit(lambda: None).result(5.0)  # everything queued before has run


def test_auto_mode_switches_run_on_one_worker_one_at_a_time():
    drv = FakeDriver()
    auto = AutoFlight(drv)
    try:
        drv.gate.clear()
        with drv.tel.lock:
            auto.switch(CopterMode.AUTO, 5, Phase.MISSION)
            auto.switch(CopterMode.AUTO, 6, Phase.MISSION)  # one in flight: dropped
            assert auto.pending == {CopterMode.AUTO, CopterMode.GUIDED}
        drv.gate.set()
        settle(auto)
        assert drv.phase is Phase.AUTO and not auto.switching and auto.pending == set()
        assert len(drv.threads) == 2  # DO_SET_MISSION_CURRENT and DO_SET_MODE of one switch
        for mode, expect in ((CopterMode.GUIDED, Phase.AUTO), (CopterMode.AUTO, Phase.AUTO),
                             (CopterMode.GUIDED, Phase.AUTO)):
            auto.switch(mode, None, expect)
            settle(auto)
        assert len(drv.threads) == 5 and len(set(drv.threads)) == 1  # one worker for every switch
        assert drv.threads[0] is not threading.current_thread() and drv.threads[0].name.startswith("mavlink-uav1-auto")
        drv.phase = Phase.HOLD  # a hold came first: the queued switch does nothing
        auto.switch(CopterMode.AUTO, 3, Phase.MISSION)
        settle(auto)
        assert len(drv.threads) == 5 and drv.phase is Phase.HOLD
    finally:
        auto.close()


def test_a_refused_auto_switch_is_recorded_and_the_flight_goes_on_guided():
    drv = FakeDriver(refuse=True)
    auto = AutoFlight(drv)
    try:
        auto.switch(CopterMode.AUTO, None, Phase.MISSION)
        settle(auto)
        assert drv.phase is Phase.MISSION and not auto.switching
        assert auto.errors == ["set mode 3 refused by the autopilot: MAV_RESULT_TEMPORARILY_REJECTED to "
                               "MAV_CMD_DO_SET_MODE"]
    finally:
        auto.close()


def test_a_closed_auto_flight_refuses_work_with_a_clear_error():
    drv = FakeDriver()
    auto = AutoFlight(drv)
    auto.close()
    with pytest.raises(ValueError, match="driver is closed"):
        auto.prepare(object())
    auto.switch(CopterMode.AUTO, None, Phase.MISSION)  # nothing to run it on: no switch in flight
    assert not auto.switching and drv.threads == []
