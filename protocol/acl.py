"""Who may say what on the bus: roles and the Zenoh ``access_control`` rules, built from the key space.

Design notes: docs/security.md (protocol/acl.py).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

from protocol import keys

ROLES = ("uav", "gcs", "planner", "detector", "gateway", "web", "video", "replay")
#: roles of the tools that attach to a running network (``skynet web``, ``video``, ``replay``)
ATTACHED_ROLES = ("web", "video", "replay")
#: the message kinds of Zenoh's ACL (zenoh 1.x ``AclMessage``)
MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable", "liveliness_token",
            "liveliness_query", "declare_liveliness_subscriber")
_USER = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
_UAV_NAME = re.compile(r"^uav([0-9]{1,3})$")
_ROLE_NAME = re.compile(r"^(gcs|planner|detector|gateway|web|video|replay)([0-9]*|[-_.][A-Za-z0-9_.-]*)$")


class Principal(NamedTuple):
    """A user name and the role it speaks for; ``uav`` is the UAV id for the ``uav`` role."""

    user: str
    role: str
    uav: int | None = None

    @property
    def subject(self) -> str:
        """The ACL subject it belongs to: one per UAV id, one per other role."""
        return f"uav{self.uav}" if self.role == "uav" else self.role


class Grant(NamedTuple):
    """Messages allowed in one direction on some key expressions (one ACL rule)."""

    flow: str  # "ingress": from the node into the router; "egress": from the router to the node
    messages: tuple[str, ...]
    key_exprs: tuple[str, ...]


# ----------------------------------------------------------------------------- users and roles
def check_user(user: str) -> str:
    if not isinstance(user, str) or not _USER.match(user):
        raise ValueError(f"user name must match [A-Za-z0-9_.-]{{1,64}}, got {user!r}")
    return user


def role_of(user: str, role: str | None = None) -> Principal:
    """The principal of ``user``: from an explicit ``role`` or from the user name.

    ``role`` is ``uavN`` (N in 1..255), ``gcs``, ``planner``, ``detector`` or ``gateway``. Without
    it the name decides: ``uav1``..``uav255`` are UAVs, and ``gcs``, ``planner``, ``detector``,
    ``gateway``, optionally followed by digits or by ``-``/``_``/``.`` and more (``gcs2``,
    ``detector-b``), are those roles. Raises ValueError when neither gives a role.
    """
    check_user(user)
    text = user if role is None else role.strip()
    m = _UAV_NAME.match(text)
    if m:
        uav = int(m.group(1))
        if not 1 <= uav <= 255:
            raise ValueError(f"{user!r}: UAV id must be in 1..255, got {uav}")
        return Principal(user, "uav", uav)
    if role is not None:
        if text in ROLES and text != "uav":
            return Principal(user, text)
        raise ValueError(f"{user!r}: unknown role {role!r}; expected uavN (1..255), gcs, planner, detector, gateway, "
                         "web, video or replay")
    m = _ROLE_NAME.match(text)
    if m:
        return Principal(user, m.group(1))
    raise ValueError(f"no role for user {user!r}: name it uavN, gcs, planner, detector or gateway, "
                     "or give it an explicit role")


def assign_roles(users: Iterable[str], roles: Mapping[str, Principal] | None = None
                 ) -> tuple[list[Principal], list[str]]:
    """Principals of ``users`` (the explicit ``roles`` first, then the name) and the users left without a role.

    A user without a role may still connect (authentication) but is denied everything.
    """
    roles = roles or {}
    found, unassigned = [], []
    for user in users:
        if user in roles:
            found.append(roles[user])
            continue
        try:
            found.append(role_of(user))
        except ValueError:
            unassigned.append(user)
    return found, unassigned


# ----------------------------------------------------------------------------- rules
_INTEREST = ("declare_subscriber", "declare_queryable", "declare_liveliness_subscriber", "liveliness_query")


def grants(fleet: str, role: str, uav: int | None = None) -> list[Grant]:
    """What ``role`` may say (ingress) and hear (egress) in ``fleet``; see the roles table of docs/security.md."""
    cam_all = keys.camera(fleet, "*")
    interest = Grant("egress", _INTEREST, (keys.fleet_all(fleet), keys.advanced(cam_all)))
    if role == "uav":
        if uav is None:
            raise ValueError("the uav role needs a UAV id")
        cam = keys.camera(fleet, uav)
        return [
            Grant("ingress", ("put",), (keys.state(fleet, uav), keys.event(fleet, uav), cam, keys.advanced(cam),
                                        keys.preview(fleet, uav))),
            Grant("ingress", ("declare_queryable",), (keys.cmd(fleet, uav), keys.advanced(cam))),
            Grant("ingress", ("reply",), (keys.cmd(fleet, uav), cam, keys.advanced(cam))),
            Grant("ingress", ("liveliness_token",), (keys.alive(fleet, uav),)),
            Grant("ingress", ("declare_subscriber",), (keys.state(fleet, "*"), keys.heartbeat(fleet))),
            Grant("ingress", ("declare_liveliness_subscriber", "liveliness_query"), (keys.alive(fleet, "*"),)),
            Grant("egress", ("put",), (keys.state(fleet, "*"), keys.heartbeat(fleet))),
            # the detector's recovery queries name every camera (``uav/*/camera/@adv/*/<zid>/<eid>/**``,
            # from its subscription to all cameras), which no per-UAV key includes: a UAV may be *asked*
            # on every camera's recovery keys, and may only *answer* with its own camera's frames
            Grant("egress", ("query",), (keys.cmd(fleet, uav), keys.advanced(cam_all))),
            Grant("egress", ("liveliness_token",), (keys.alive(fleet, "*"),)),
            interest,
        ]
    if uav is not None:
        raise ValueError(f"only the uav role takes a UAV id, not {role!r}")
    if role == "gcs":
        everything = keys.fleet_all(fleet)
        return [
            Grant("ingress", ("put",), (keys.heartbeat(fleet), keys.gcs_event(fleet))),
            Grant("ingress", ("query",), (keys.cmd(fleet, "*"), keys.planner(fleet))),
            Grant("ingress", ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"),
                  (everything,)),
            # the mission log records every capture frame, so it recovers the lost ones as the detector does (the
            # answers come on the camera keys themselves)
            Grant("ingress", ("declare_subscriber", "query"), (cam_all, keys.advanced(cam_all))),
            Grant("egress", ("put", "liveliness_token"), (everything,)),
            Grant("egress", ("put", "reply"), (cam_all, keys.advanced(cam_all))),
            Grant("egress", ("reply",), (keys.cmd(fleet, "*"), keys.planner(fleet))),
            interest,
        ]
    if role == "planner":
        return [Grant("ingress", ("declare_queryable", "reply"), (keys.planner(fleet),)),
                Grant("ingress", ("liveliness_token",), (keys.rcu_alive(fleet, "planner"),)),
                Grant("ingress", ("put",), (keys.rcu_event(fleet, "planner"), keys.rcu_stats(fleet, "planner"))),
                Grant("egress", ("query",), (keys.planner(fleet),)), interest]
    if role == "detector":
        return [
            Grant("ingress", ("declare_subscriber", "query"), (cam_all, keys.advanced(cam_all))),
            # every instance (detector, detector-K: services.detector.partition) on its own keys
            Grant("ingress", ("put",), (keys.defects(fleet), keys.rcu_instances(fleet, "detector", "event"),
                                        keys.rcu_instances(fleet, "detector", "stats"))),
            Grant("ingress", ("liveliness_token",), (keys.rcu_instances(fleet, "detector", "alive"),)),
            Grant("egress", ("put", "reply"), (cam_all, keys.advanced(cam_all))),
            interest,
        ]
    if role == "gateway":
        both = (keys.fleet_all(fleet), keys.advanced(cam_all))
        return [Grant("ingress", MESSAGES, both), Grant("egress", MESSAGES, both)]
    if role in ATTACHED_ROLES:
        return attached_grants(fleet, role)
    raise ValueError(f"unknown role {role!r}; expected one of {ROLES}")


def attached_grants(fleet: str, role: str) -> list[Grant]:
    """The grants of the tools that attach to a running network (the roles table of docs/security.md): ``web`` and ``video`` read
    (the live fleet and its replay fleet), ``replay`` writes the replay fleet only."""
    replay = keys.replay_fleet(fleet)
    if role == "replay":
        return [Grant("ingress", ("put",), (keys.fleet_all(replay),)),
                Grant("egress", _INTEREST, (keys.fleet_all(replay),))]
    if role == "web":
        seen: tuple[str, ...] = (keys.fleet_all(fleet), keys.fleet_all(replay))
    elif role == "video":
        seen = tuple(k for f in (fleet, replay) for k in (keys.preview(f, "*"), keys.camera(f, "*")))
    else:
        raise ValueError(f"{role!r} is not a role of an attached tool ({', '.join(ATTACHED_ROLES)})")
    return [Grant("ingress", ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"), seen),
            Grant("egress", ("put", "liveliness_token"), seen),
            Grant("egress", _INTEREST, (keys.fleet_all(fleet), keys.fleet_all(replay)))]


def access_control(fleet: str, principals: Iterable[Principal], by: str = "usernames") -> dict[str, Any]:
    """The router's ``access_control`` object (JSON-ready): default deny, one subject per UAV id and per role
    of ``principals`` (:func:`assign_roles`; a user without one gets the default, deny), named ``by``
    ``usernames`` or ``cert_common_names`` (mutual TLS: the certificate's common name names the role).

    >>> acl = access_control("demo", [role_of("uav1"), role_of("gcs")])
    >>> [s["id"] for s in acl["subjects"]]
    ['uav1', 'gcs']
    >>> acl["subjects"][0]["usernames"]
    ['uav1']
    """
    keys.fleet_root(fleet)  # validates the fleet name
    if by not in ("usernames", "cert_common_names"):
        raise ValueError(f"subjects by usernames or cert_common_names, not {by!r}")
    members: dict[str, list[Principal]] = {}
    for p in principals:
        if not isinstance(p, Principal):
            raise ValueError(f"expected a Principal, got {p!r}")
        members.setdefault(p.subject, []).append(p)
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for subject, ps in members.items():
        ids = []
        for i, g in enumerate(grants(fleet, ps[0].role, ps[0].uav)):
            rid = f"{subject}-{g.flow}-{i}"
            rules.append({"id": rid, "messages": list(g.messages), "flows": [g.flow], "permission": "allow",
                          "key_exprs": list(g.key_exprs)})
            ids.append(rid)
        usernames = sorted({p.user for p in ps})
        subjects.append({"id": subject, by: usernames})
        policies.append({"id": f"{subject}-policy", "rules": ids, "subjects": [subject]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def cert_access_control(fleet: str, names: Iterable[str]) -> dict[str, Any]:
    """The ``access_control`` of a mutual-TLS node: subjects by certificate common name (the role, ``.gN`` after a reissue).

    The gateway lists every node of the fleet; an edge lists the gateway and the other UAVs, the
    nodes that may link to it (SkyNet): a UAV may then put only its own keys on the mesh too, and
    anything else that reaches an edge directly (a ground station, an attacker with some certificate)
    is denied everything.
    """
    from protocol.keyset import role_of_cn

    return access_control(fleet, [role_of(n, role_of_cn(n)) for n in names], by="cert_common_names")
