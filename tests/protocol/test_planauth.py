"""A plan bound to its request and signed by the planner; one answer per request (protocol.planauth)."""

from __future__ import annotations

import functools

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from protocol import codec, planauth
from protocol.keyset import KeySet
from protocol.messages import MissionPlan, PlanRequest, Signed
from protocol.scenario import load_scenario
from protocol.signing import Signer
from services.planner.service import answer

TO = "skynet/test/rcu/planner/plan"


@functools.lru_cache(maxsize=1)
def _base() -> tuple[PlanRequest, MissionPlan]:
    req = PlanRequest(request_id=7, nonce=planauth.new_nonce(), scenario=load_scenario(), particles=10, iterations=5)
    return req, answer(req)


@pytest.fixture
def planner_key() -> Ed25519PrivateKey:
    return Ed25519PrivateKey.generate()


def test_the_planner_binds_its_answer_to_the_request():
    req, plan = _base()
    assert plan.request_id == 7 and plan.nonce == req.nonce
    assert plan.scenario_digest == planauth.scenario_digest(req.scenario) and len(plan.scenario_digest) == 64
    assert planauth.binding_problem(plan, req) == ""


def test_the_scenario_digest_changes_with_any_field_and_survives_the_wire():
    sc = load_scenario()
    d = planauth.scenario_digest(sc)
    assert planauth.scenario_digest(codec.decode(codec.encode(PlanRequest(scenario=sc))).scenario) == d
    wider = sc.model_copy(update={"box": sc.box.model_copy(update={"hi": (sc.box.hi[0], sc.box.hi[1], 120.0)})})
    assert planauth.scenario_digest(wider) != d


def test_a_plan_for_another_request_nonce_or_scenario_is_refused():
    req, plan = _base()
    assert "request 8" in planauth.binding_problem(plan.model_copy(update={"request_id": 8}), req)
    assert "another request's nonce" in planauth.binding_problem(plan.model_copy(update={"nonce": "ab" * 16}), req)
    assert "nonce" in planauth.binding_problem(plan.model_copy(update={"nonce": ""}), req)
    assert "another scenario" in planauth.binding_problem(plan.model_copy(update={"scenario_digest": "0" * 64}), req)
    assert "no scenario digest" in planauth.binding_problem(plan.model_copy(update={"scenario_digest": ""}), req)


def test_only_a_plan_signed_with_the_planners_key_for_its_key_is_taken(planner_key):
    req, plan = _base()
    good = Signer("planner", planner_key).sign(plan, TO)
    verifier = planauth.plan_verifier(planner_key.public_key())
    assert planauth.open_answer(good, req, TO, verifier) == plan
    # unsigned, another key, another signer name, another addressee, a tampered body, replayed
    with pytest.raises(planauth.PlanRefused, match="^unsigned"):
        planauth.open_answer(plan, req, TO, verifier)
    rogue = Ed25519PrivateKey.generate()
    with pytest.raises(planauth.PlanRefused, match="^unknown-signer"):
        planauth.open_answer(Signer("planner", rogue).sign(plan, TO), req, TO, verifier)
    with pytest.raises(planauth.PlanRefused, match="^wrong-signer"):
        planauth.open_answer(Signer("gcs", planner_key).sign(plan, TO), req, TO, verifier)
    with pytest.raises(planauth.PlanRefused, match="^wrong-addressee"):
        planauth.open_answer(Signer("planner", planner_key).sign(plan, "skynet/other/rcu/planner/plan"), req, TO,
                             verifier)
    other = Signer("planner", rogue).sign(plan.model_copy(update={"cost": 1.0}), TO)
    with pytest.raises(planauth.PlanRefused, match="^bad-signature"):
        planauth.open_answer(good.model_copy(update={"body": other.body}), req, TO, verifier)
    # signed by the planner, but for an earlier request: the signature does not make it fresh (the nonce does)
    old = Signer("planner", planner_key).sign(plan.model_copy(update={"nonce": "cd" * 16}), TO)
    with pytest.raises(planauth.PlanRefused, match="^unbound: the plan carries another request's nonce"):
        planauth.open_answer(old, req, TO, verifier)
    # a revoked planner key
    revoked = planauth.plan_verifier(planner_key.public_key(), revoked={good.kid})
    with pytest.raises(planauth.PlanRefused, match="^revoked"):
        planauth.open_answer(Signer("planner", planner_key).sign(plan, TO), req, TO, revoked)


def test_without_a_verifier_an_unsigned_plan_is_taken_but_still_bound():
    req, plan = _base()
    assert planauth.open_answer(plan, req, TO, None) == plan
    assert planauth.open_answer(Signer("planner", Ed25519PrivateKey.generate()).sign(plan, TO), req, TO, None) == plan
    with pytest.raises(planauth.PlanRefused, match="^unbound"):
        planauth.open_answer(plan.model_copy(update={"nonce": ""}), req, TO, None)
    with pytest.raises(planauth.PlanRefused, match="^malformed"):
        planauth.open_answer(req, req, TO, None)


def test_two_different_answers_are_a_conflict_never_the_last_one_wins(planner_key):
    req, plan = _base()
    sign = Signer("planner", planner_key).sign
    verifier = planauth.plan_verifier(planner_key.public_key())
    climbing = plan.model_copy(update={"cost": plan.cost + 1.0})
    with pytest.raises(planauth.Conflict, match="2 different plans answered plan request 7"):
        planauth.choose([sign(plan, TO), sign(climbing, TO)], req, TO, verifier)
    # the same order reversed: no answer wins by coming first or last
    verifier = planauth.plan_verifier(planner_key.public_key())
    with pytest.raises(planauth.Conflict):
        planauth.choose([sign(climbing, TO), sign(plan, TO)], req, TO, verifier)
    # a stolen key signing with a far-future sequence first does not silence the other answer
    future = Signer("planner", planner_key)
    future._last = 2 ** 62  # its sequence far ahead; its stamp now
    with pytest.raises(planauth.Conflict):
        planauth.choose([future.sign(climbing, TO), sign(plan, TO)], req, TO,
                        planauth.plan_verifier(planner_key.public_key()))


def test_refused_answers_are_named_and_the_valid_one_taken(planner_key):
    req, plan = _base()
    sign = Signer("planner", planner_key).sign
    verifier = planauth.plan_verifier(planner_key.public_key())
    rogue = Signer("planner", Ed25519PrivateKey.generate()).sign(plan.model_copy(update={"cost": 0.0}), TO)
    choice = planauth.choose([sign(plan, TO), plan, rogue], req, TO, verifier)
    assert choice.plan == plan and choice.accepted == 1
    assert len(choice.refused) == 2 and choice.refused[0].startswith("answer 2 refused: unsigned")
    assert choice.refused[1].startswith("answer 3 refused: unknown-signer")
    # two planners with the same seed give the same plan (planning time aside): one plan, no conflict,
    # whichever signed first
    twin = sign(plan.model_copy(update={"planning_time_s": plan.planning_time_s + 3.0}), TO)
    choice = planauth.choose([twin, sign(plan, TO)], req, TO, verifier)
    assert choice.plan is not None and choice.accepted == 2 and not choice.refused
    # nothing valid: no plan, every reason
    choice = planauth.choose([plan, rogue], req, TO, planauth.plan_verifier(planner_key.public_key()))
    assert choice.plan is None and len(choice.refused) == 2


def test_the_wire_types_refuse_a_malformed_nonce_or_digest():
    req, plan = _base()
    for bad in ("xyz", "AB" * 16, "a" * 65, "ab" * 4):
        with pytest.raises(codec.CodecError):
            codec.decode(codec.encode(req.model_copy(update={"nonce": bad})), PlanRequest)
    with pytest.raises(codec.CodecError):
        codec.decode(codec.encode(plan.model_copy(update={"scenario_digest": "f" * 63})), MissionPlan)
    assert isinstance(codec.decode(codec.encode(Signer("planner", Ed25519PrivateKey.generate()).sign(plan, TO))),
                      Signed)


def test_the_ground_station_reads_the_planners_public_key_from_the_key_set_or_says_what_is_missing(tmp_path):
    from services.keys import init

    root = init(tmp_path / "keys", uavs=1)
    req, plan = _base()
    signed = KeySet(root, "planner").signer().sign(plan, TO)  # what `skynet planner --keys` answers with
    assert planauth.open_answer(signed, req, TO, planauth.plan_verifier(planauth.planner_public_key(root))) == plan
    assert not (root / "trust" / "planner.pub").exists()  # the UAVs never trust the planner's signature
    (root / "planner" / "sign.pub").unlink()
    with pytest.raises(ValueError, match="cannot read the planner's public key"):
        planauth.planner_public_key(root)
