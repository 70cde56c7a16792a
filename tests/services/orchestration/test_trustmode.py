"""services.orchestration.trustmode: what the secure mode says of an impairment's datagram effects."""

from __future__ import annotations

from services.orchestration.trustmode import datagram_warnings


def test_a_loss_on_the_best_effort_class_in_the_secure_mode_is_said_to_be_a_delay():
    """A composed run with `--impair 'all/udp=loss 15%'` dropped nothing (the class rides TLS) and said nothing."""
    (line,) = datagram_warnings(["all/udp=loss 15%", "uav2=delay 50ms", "uav1/tcp=loss 5%"])
    assert line.startswith("--impair 'all/udp=loss 15%'") and "retransmission delay" in line and "--insecure" in line
    assert len(datagram_warnings(["loss 2%", "uav3=duplicate 1%", "uav1-uav2=reorder 10%"])) == 3
    assert datagram_warnings([]) == []
