"""protocol/keyset.py: the revocation watch (the key set's layout is tested with its tool, tests/services/test_keys.py)."""

from __future__ import annotations

import logging

from protocol.keyset import KeySet, RevocationWatch
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
