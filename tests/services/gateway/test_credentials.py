"""Credentials: generated files, the bus options that carry a user and password, the gateway's options."""

from __future__ import annotations

import argparse
import json
import stat

import pytest
import zenoh

from protocol import acl
from protocol.bus import PASSWORD_ENV, BusConfig, add_bus_args, config_from_args
from services.gateway.credentials import generate
from services.gateway.service import GatewayConfig, build_parser, security_options


def test_generate_writes_private_files(tmp_path):
    creds = generate(tmp_path / "c", ["uav1", "uav2", "gcs", "detector"])
    assert set(creds.passwords) == {"uav1", "uav2", "gcs", "detector"}
    assert len(set(creds.passwords.values())) == 4 and all(len(p) >= 20 for p in creds.passwords.values())
    assert acl.read_users(creds.users_file) == creds.passwords
    mesh_file = json.loads(creds.mesh_config.read_text())["transport"]["auth"]["usrpwd"]["dictionary_file"]
    assert acl.read_users(mesh_file) == {u: creds.passwords[u] for u in ("uav1", "uav2")}  # UAVs only
    for f in (creds.users_file, creds.mesh_config, mesh_file):
        assert stat.S_IMODE((tmp_path / "c" / f).stat().st_mode) == 0o600
    conf = zenoh.Config.from_file(str(creds.mesh_config))
    assert json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file")) == mesh_file
    with pytest.raises(ValueError):
        generate(tmp_path / "d", ["uav1", "uav1"])


def _args(argv):
    parser = argparse.ArgumentParser()
    add_bus_args(parser)
    return parser.parse_args(argv)


def test_bus_config_carries_credentials_and_never_shows_the_password(monkeypatch, tmp_path):
    monkeypatch.delenv(PASSWORD_ENV, raising=False)
    cfg = config_from_args(_args(["--user", "uav1", "--password", "s3cret-pw"]))
    assert "s3cret-pw" not in repr(cfg) and "s3cret-pw" not in str(cfg.model_dump())
    usrpwd = json.loads(cfg.to_zenoh().get_json("transport/auth/usrpwd"))
    assert usrpwd["user"] == "uav1" and usrpwd["password"] == "s3cret-pw"
    # the password from the environment, and only when a user is given
    monkeypatch.setenv(PASSWORD_ENV, "from-env")
    assert config_from_args(_args(["--user", "gcs"])).password.get_secret_value() == "from-env"
    assert config_from_args(_args(["--user", "gcs", "--password", "flag"])).password.get_secret_value() == "flag"
    plain = config_from_args(_args([]))
    assert plain.user is None and plain.password is None
    assert json.loads(plain.to_zenoh().get_json("transport/auth/usrpwd"))["user"] is None
    # a user without a password is refused with a message that names the remedy
    monkeypatch.delenv(PASSWORD_ENV)
    with pytest.raises(ValueError, match=PASSWORD_ENV):
        config_from_args(_args(["--user", "gcs"])).to_zenoh()
    # the user/password go in path by path: a dictionary from --config stays
    cfgfile = tmp_path / "z.json5"
    cfgfile.write_text(json.dumps({"transport": {"auth": {"usrpwd": {"dictionary_file": "/x/users.txt"}}}}))
    usrpwd = json.loads(BusConfig(config_file=str(cfgfile), user="u", password="p").to_zenoh()
                        .get_json("transport/auth/usrpwd"))
    assert usrpwd == {"user": "u", "password": "p", "dictionary_file": "/x/users.txt"}


def test_gateway_security_options(tmp_path):
    users = tmp_path / "users.txt"
    users.write_text("uav1:a\ngcs:b\ndrone:c\nvisitor:d\n")
    roles = tmp_path / "roles.txt"
    roles.write_text("drone:uav5\n")
    parse = build_parser().parse_args
    assert security_options(parse([])) == {}
    auth_only = security_options(parse(["--users", str(users)]))
    assert auth_only == {"dictionary_file": str(users)}
    full = security_options(parse(["--users", str(users), "--acl", "--roles", str(roles), "--fleet", "x"]))
    subjects = {s["id"]: s["usernames"] for s in full["access_control"]["subjects"]}
    assert subjects == {"uav1": ["uav1"], "gcs": ["gcs"], "uav5": ["drone"]}
    conf = GatewayConfig(mode="router", **full).to_zenoh()
    assert json.loads(conf.get_json("access_control/default_permission")) == "deny"
    assert json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file")) == str(users)
    for argv, match in ((["--acl"], "--users"), (["--roles", str(roles)], "--users"),
                        (["--users", str(users), "--roles", str(roles)], "--acl")):
        with pytest.raises(ValueError, match=match):
            security_options(parse(argv))
    roles.write_text("stranger:gcs\n")
    with pytest.raises(ValueError, match="stranger"):
        security_options(parse(["--users", str(users), "--acl", "--roles", str(roles)]))


def test_generated_passwords_never_look_like_options(tmp_path):
    from services.gateway.credentials import _password

    assert not any(_password(3).startswith("-") for _ in range(2000))
