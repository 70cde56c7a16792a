"""A plan's authority: bound to its request, signed by the planner, one answer per request.

Design notes: docs/security.md (protocol/planauth.py).
"""

from __future__ import annotations

import hashlib
import json
import secrets
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from . import codec
from .messages import Message, MissionPlan, PlanRequest, Signed
from .scenario import Scenario
from .signing import ReplayStore, TrustError, Verifier, load_public, unverified_inner

#: the signer name (key set role) whose signature a plan must carry
PLANNER = "planner"
#: a plan's signature stamp may be this far from the ground station's clock, s (the nonce is what
#: makes an answer fresh; the stamp only bounds clock skew between the two machines)
PLAN_STALE_S = 120.0


class PlanRefused(ValueError):
    """One answer refused: ``code`` (unsigned, bad-signature, unbound, wrong-request, ...) and why."""

    def __init__(self, code: str, detail: str):
        super().__init__(f"{code}: {detail}")
        self.code = code
        self.detail = detail


class Conflict(ValueError):
    """Two or more different accepted answers to one request: no plan is taken."""


def new_nonce() -> str:
    """A fresh request nonce: 128 random bits as 32 hex digits (:mod:`secrets`)."""
    return secrets.token_hex(16)


def scenario_digest(scenario: Scenario) -> str:
    """SHA-256 (hex) of the scenario's canonical JSON (sorted keys, no spaces): equal on both ends
    for the same typed scenario, different for any change of any field."""
    doc = json.dumps(scenario.model_dump(mode="json"), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(doc.encode("utf-8")).hexdigest()


def bind(plan: MissionPlan, request: PlanRequest) -> MissionPlan:
    """The planner's side: ``plan`` carrying its request's id, nonce and scenario digest."""
    return plan.model_copy(update={"request_id": request.request_id, "nonce": request.nonce,
                                   "scenario_digest": scenario_digest(request.scenario)})


def binding_problem(plan: MissionPlan, request: PlanRequest, digest: str | None = None) -> str:
    """Why ``plan`` does not answer ``request`` (id, nonce, scenario digest), or ``""``.

    ``digest`` is the request's :func:`scenario_digest` when the caller already has it.
    """
    if plan.request_id != request.request_id:
        return f"answers request {plan.request_id}, not {request.request_id}"
    if request.nonce and plan.nonce != request.nonce:
        return "does not carry the request's nonce" if not plan.nonce else "carries another request's nonce"
    want = digest or scenario_digest(request.scenario)
    if plan.scenario_digest != want:
        return ("carries no scenario digest" if not plan.scenario_digest
                else "was planned for another scenario (digest differs)")
    return ""


def planner_public_key(root: str | Path) -> Ed25519PublicKey:
    """The planner's public signing key of the key set folder ``root`` (``planner/sign.pub``).

    Deliberately not ``trust/``: that folder lists the signers the UAVs obey, and a UAV must never
    take a command signed by the planner.
    """
    path = Path(root) / PLANNER / "sign.pub"
    try:
        return load_public(path)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the planner's public key, which the ground station verifies plans "
                         f"with ({exc.strerror or exc}); copy planner/sign.pub of the key set there") from None


class _NonceFreshness(ReplayStore):
    """No sequence window for plans: an answer is fresh by the request's nonce it carries (checked by
    :func:`binding_problem`), and every answer must be judged. A sequence window would let the first
    of two answers decide which other is "replayed" (a stolen key signing with a far-future sequence
    would silence the real planner instead of making a :class:`Conflict`)."""

    def accept(self, stream: str, seq: int) -> bool:
        return True


def plan_verifier(public: Ed25519PublicKey | Iterable[Ed25519PublicKey], revoked: Iterable[str] = ()) -> Verifier:
    """A verifier that trusts the planner's key(s) only; freshness is the request's nonce."""
    keys = [public] if isinstance(public, Ed25519PublicKey) else list(public)
    return Verifier({PLANNER: keys}, revoked, _NonceFreshness(None), stale_s=PLAN_STALE_S)


def open_answer(answer: Message, request: PlanRequest, to: str, verifier: Verifier | None,
                digest: str | None = None) -> MissionPlan:
    """The plan in one answer to ``request`` sent on key ``to``; :class:`PlanRefused` why not.

    With a ``verifier`` the answer must be a plan signed by the planner's key for ``to``; without
    one (``--insecure``) an unsigned plan is taken (a signed one is opened unverified), and only
    the binding and the scenario checks stand between it and the fleet.
    """
    if verifier is not None:
        if not isinstance(answer, Signed):
            raise PlanRefused("unsigned", f"a {getattr(answer, 'TYPE', type(answer).__name__)} without the "
                                          "planner's signature")
        if answer.signer != PLANNER:
            raise PlanRefused("wrong-signer", f"signed by {answer.signer[:64]!r}, not the planner")
        try:
            plan = verifier.verify(answer, to, MissionPlan).message
        except TrustError as exc:
            raise PlanRefused(exc.reason.value, exc.detail) from None
    else:
        try:
            plan = unverified_inner(answer)
        except (TrustError, codec.CodecError) as exc:
            raise PlanRefused("malformed", str(exc)) from None
    if not isinstance(plan, MissionPlan):
        raise PlanRefused("malformed", f"a {getattr(plan, 'TYPE', type(plan).__name__)}, not a plan")
    why = binding_problem(plan, request, digest)
    if why:
        raise PlanRefused("unbound", f"the plan {why}")
    return plan


def fingerprint(plan: MissionPlan) -> str:
    """SHA-256 of what the plan commits the fleet to (everything but how long planning took)."""
    return hashlib.sha256(codec.encode(plan.model_copy(update={"planning_time_s": 0.0}))).hexdigest()


@dataclass
class Choice:
    """What one request's answers came to: the plan (or None), and every refusal with its reason."""

    plan: MissionPlan | None
    refused: list[str] = field(default_factory=list)
    accepted: int = 0  # answers that passed signature and binding (identical ones included)


def choose(answers: Sequence[Message], request: PlanRequest, to: str, verifier: Verifier | None) -> Choice:
    """Judge every answer of one request (:func:`open_answer`); :class:`Conflict` when the accepted
    ones are not all the same plan (two planners with the same seed agree: one plan)."""
    digest = scenario_digest(request.scenario)
    out = Choice(None)
    plans: dict[str, MissionPlan] = {}
    for n, answer in enumerate(answers, start=1):
        try:
            plan = open_answer(answer, request, to, verifier, digest)
        except PlanRefused as exc:
            out.refused.append(f"answer {n} refused: {exc}")
            continue
        out.accepted += 1
        plans.setdefault(fingerprint(plan), plan)
    if len(plans) > 1:
        raise Conflict(f"{len(plans)} different plans answered plan request {request.request_id} "
                       f"({out.accepted} answers passed the planner's signature and the binding): a second "
                       "session answers as the planner; no plan is taken")
    out.plan = next(iter(plans.values()), None)
    return out
