"""Signed envelopes: every refusal has its reason; a forgery never moves the replay window."""

from __future__ import annotations

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from protocol import codec
from protocol.messages import Heartbeat, Land, Signed, Takeoff
from protocol.signing import Refusal, ReplayStore, Signer, TrustError, Verifier, key_id

TO = "skynet/demo/uav/1/cmd"


class Clock:
    def __init__(self, t: float = 1.8e9):
        self.t = t

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def clock():
    return Clock()


@pytest.fixture
def gcs(clock):
    return Signer("gcs", Ed25519PrivateKey.generate(), clock=clock)


def verifier(gcs, clock, **kw):
    return Verifier({"gcs": [gcs._key.public_key()]}, clock=clock, **kw)


def refusal(v: Verifier, msg, to=TO, expect=None) -> Refusal:
    with pytest.raises(TrustError) as info:
        v.verify(msg, to, expect)
    return info.value.reason


def test_valid_command_verifies_and_survives_the_codec(gcs, clock):
    v = verifier(gcs, clock)
    env = codec.decode(codec.encode(gcs.sign(Land(uav=1, cmd_id=7), TO)))
    got = v.verify(env, TO, (Land, Takeoff))
    assert got.message == Land(uav=1, cmd_id=7) and got.signer == "gcs"


def test_unsigned_refused(gcs, clock):
    assert refusal(verifier(gcs, clock), Land(uav=1, cmd_id=1)) == Refusal.UNSIGNED


def test_unknown_signer_refused(gcs, clock):
    other = Signer("gcs", Ed25519PrivateKey.generate(), clock=clock)  # same name, key not trusted
    assert refusal(verifier(gcs, clock), other.sign(Land(uav=1, cmd_id=1), TO)) == Refusal.UNKNOWN_SIGNER
    renamed = gcs.sign(Land(uav=1, cmd_id=1), TO).model_copy(update={"signer": "uav2"})
    assert refusal(verifier(gcs, clock), renamed) == Refusal.UNKNOWN_SIGNER


def test_revoked_key_refused(gcs, clock):
    v = verifier(gcs, clock, revoked=[key_id(gcs._key.public_key())])
    assert refusal(v, gcs.sign(Land(uav=1, cmd_id=1), TO)) == Refusal.REVOKED


@pytest.mark.parametrize("field,value", [
    ("body", None), ("to", "skynet/demo/uav/3/cmd"), ("seq", 10**15), ("stamp", 1.8e9 + 1), ("type", "cmd.takeoff"),
])
def test_tampered_envelope_refused(gcs, clock, field, value):
    env = gcs.sign(Land(uav=1, cmd_id=1), TO)
    if field == "body":
        import base64
        value = base64.b64encode(codec.encode(Takeoff(uav=1, cmd_id=1))).decode()
    bad = env.model_copy(update={field: value})
    assert refusal(verifier(gcs, clock), bad, to=bad.to) == Refusal.BAD_SIGNATURE


def test_other_signature_refused(gcs, clock):
    a, b = gcs.sign(Land(uav=1, cmd_id=1), TO), gcs.sign(Land(uav=1, cmd_id=2), TO)
    assert refusal(verifier(gcs, clock), a.model_copy(update={"sig": b.sig})) == Refusal.BAD_SIGNATURE
    assert refusal(verifier(gcs, clock), a.model_copy(update={"sig": "!!"})) == Refusal.MALFORMED


def test_relayed_to_another_addressee_refused(gcs, clock):
    env = gcs.sign(Land(uav=3, cmd_id=1), "skynet/demo/uav/3/cmd")
    assert refusal(verifier(gcs, clock), env, to=TO) == Refusal.WRONG_ADDRESSEE


def test_stale_refused_both_ways(gcs, clock):
    v = verifier(gcs, clock, stale_s=5.0)
    env = gcs.sign(Land(uav=1, cmd_id=1), TO)
    clock.t += 5.5
    assert refusal(v, env) == Refusal.STALE
    clock.t -= 11.0  # from the future (a clock far ahead)
    assert refusal(v, env) == Refusal.STALE
    clock.t += 5.5
    assert v.verify(env, TO).seq == env.seq


def test_replayed_and_reordered_refused(gcs, clock):
    v = verifier(gcs, clock)
    first, second = gcs.sign(Land(uav=1, cmd_id=1), TO), gcs.sign(Land(uav=1, cmd_id=2), TO)
    assert second.seq > first.seq  # the clock did not move: still strictly increasing
    v.verify(second, TO)
    assert refusal(v, second) == Refusal.REPLAYED
    assert refusal(v, first) == Refusal.REPLAYED  # re-ordered: older than the last accepted


def test_streams_are_per_addressee(gcs, clock):
    v = verifier(gcs, clock)
    hb = gcs.sign(Heartbeat(seq=1, stamp=clock.t), "skynet/demo/gcs/heartbeat")
    cmd = gcs.sign(Land(uav=1, cmd_id=1), TO)  # signed after, delivered before: another stream
    v.verify(cmd, TO)
    v.verify(hb, "skynet/demo/gcs/heartbeat")


def test_forgery_does_not_move_the_window(gcs, clock):
    """pymavlink's lesson: a forged message with a huge sequence must not lock the real sender out."""
    v = verifier(gcs, clock)
    forged = gcs.sign(Land(uav=1, cmd_id=1), TO).model_copy(update={"seq": 2**62})
    assert refusal(v, forged) == Refusal.BAD_SIGNATURE
    assert v.verify(gcs.sign(Land(uav=1, cmd_id=2), TO), TO)


def test_unexpected_body_type_refused(gcs, clock):
    env = gcs.sign(Heartbeat(seq=1, stamp=clock.t), TO)
    assert refusal(verifier(gcs, clock), env, expect=(Land,)) == Refusal.MALFORMED


def test_replay_window_persists_across_a_restart(gcs, clock, tmp_path):
    path = tmp_path / "replay.json"
    env = gcs.sign(Land(uav=1, cmd_id=1), TO)
    verifier(gcs, clock, replay=ReplayStore(path)).verify(env, TO)
    restarted = verifier(gcs, clock, replay=ReplayStore(path))
    assert refusal(restarted, env) == Refusal.REPLAYED
    assert restarted.verify(gcs.sign(Land(uav=1, cmd_id=2), TO), TO)


def test_corrupt_replay_file_is_an_error(tmp_path):
    path = tmp_path / "replay.json"
    path.write_text("{not json")
    with pytest.raises(ValueError, match="unreadable"):
        ReplayStore(path)


def test_envelope_schema_rejects_bad_key_id():
    with pytest.raises(codec.CodecError):
        codec.decode(codec.encode(Signed(signer="gcs", kid="0" * 16, seq=1, stamp=1.0, to=TO, type="x", body="",
                                         sig="")).replace(b"0000000000000000", b"zzzzzzzzzzzzzzzz"))
