"""protocol/keyset.py: the revocation and admission watches (the key set's layout is tested with its tool, tests/services/test_keys.py)."""

from __future__ import annotations

import logging

from protocol.keyset import AdmissionWatch, KeySet, RevocationWatch
from protocol.signing import key_id, load_public
from services.keys import init, revoke


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_a_revocation_written_beside_a_running_node_is_seen_at_its_next_look(tmp_path, caplog):
    root = init(tmp_path / "k", uavs=1)
    clock = Clock()
    watch = RevocationWatch(KeySet(root, "uav1"), min_interval_s=1.0, clock=clock)
    clock.t = 5.0
    assert watch() is None  # nothing changed
    kid = key_id(load_public(root / "gcs" / "sign.pub"))
    revoke(root, str(root / "gcs" / "sign.pub"))
    clock.t = 5.5
    assert watch() is None  # looked at less than a second ago
    clock.t = 6.0
    assert watch() == frozenset({kid})
    clock.t = 7.0
    assert watch() is None  # returned once per change
    # a file that does not parse (being rewritten, or damaged): the last good set stays, one warning
    (root / "revoked.txt").write_text(f"{kid}\nnot a key id\n")
    with caplog.at_level(logging.WARNING, logger="skynet.keyset"):
        for t in (8.0, 9.0, 10.0):
            clock.t = t
            assert watch() is None
    assert sum("revocations unreadable" in r.message and "line 2" in r.message for r in caplog.records) == 1
    (root / "revoked.txt").write_text("")  # un-revoked
    clock.t = 11.0
    assert watch() == frozenset()


def test_a_change_of_the_admitted_certificates_is_taken_once_two_reads_agree(caplog):
    """``skynet keys revoke|reissue`` beside a running node: the new names once two looks a period apart agree
    (a key set being rewritten may be read between its files' writes); a damaged key set: one warning, no change."""
    clock, on_disk = Clock(), {"names": ["gateway", "uav1", "uav2"]}

    def read() -> list[str]:
        if isinstance(on_disk["names"], Exception):
            raise on_disk["names"]
        return list(on_disk["names"])

    watch = AdmissionWatch(read, read(), min_interval_s=1.0, clock=clock)
    clock.t = 1.0
    assert watch() is None and watch.current == ["gateway", "uav1", "uav2"]
    on_disk["names"] = ["gateway", "uav1"]
    clock.t = 1.5
    assert watch() is None  # looked at less than a period ago
    clock.t = 2.0
    assert watch() is None  # seen once: not yet
    clock.t = 3.0
    assert watch() == ["gateway", "uav1"] and watch.current == ["gateway", "uav1"]
    clock.t = 4.0
    assert watch() is None  # once per change
    on_disk["names"] = ["gateway"]  # a half-written set, read once, then the final one
    clock.t = 5.0
    assert watch() is None
    on_disk["names"] = ["gateway", "uav1", "uav2.g2"]
    clock.t = 6.0
    assert watch() is None  # differs from the half-written read: not taken
    clock.t = 7.0
    assert watch() == ["gateway", "uav1", "uav2.g2"]
    on_disk["names"] = ValueError("certs.txt line 3: not a node")
    with caplog.at_level(logging.WARNING, logger="skynet.keyset"):
        for t in (8.0, 9.0, 10.0):
            clock.t = t
            assert watch() is None
    assert sum("key set unreadable" in r.message and "line 3" in r.message for r in caplog.records) == 1
    assert watch.current == ["gateway", "uav1", "uav2.g2"]
    on_disk["names"] = ["uav2.g2", "gateway", "uav1"]  # the same names in another order: no change, no reopen
    for t in (11.0, 12.0, 13.0):
        clock.t = t
        assert watch() is None
