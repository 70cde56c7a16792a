"""services.composekeys: docker compose's key set is reused, made once in an empty folder, or refused."""

import os

import pytest

from protocol.keyset import KeySet
from services import keys
from services.composekeys import main, missing_sans, prepare


def test_an_empty_folder_gets_a_set_with_the_side_cars_names(tmp_path):
    folder = tmp_path / "compose"
    folder.mkdir()  # what docker makes of a missing bind-mount source
    what, warnings = prepare(folder, 3, ["netem-uav2", "netem-uav1-uav2"], owner_of=tmp_path)
    assert what == "made" and warnings == []
    assert KeySet(folder, "uav3").signer() and missing_sans(folder, ["netem-uav2", "netem-uav1-uav2"]) == []
    assert missing_sans(folder, ["other"], role="uav1") == ["other"]
    st = tmp_path.stat()
    assert {(os.stat(p).st_uid, os.stat(p).st_gid) for p in folder.rglob("*")} == {(st.st_uid, st.st_gid)}


def test_a_complete_set_is_reused_untouched_and_a_missing_san_is_a_warning(tmp_path):
    keys.init(tmp_path / "own", 3)  # e.g. your own set, without the side-cars' names
    before = (tmp_path / "own" / "gcs" / "sign.key").read_bytes()
    what, warnings = prepare(tmp_path / "own", 3, ["netem-uav2"])
    assert what == "reused" and (tmp_path / "own" / "gcs" / "sign.key").read_bytes() == before
    assert len(warnings) == 1 and "netem-uav2" in warnings[0]


@pytest.mark.parametrize("case", ["partial", "not-a-set"])
def test_anything_else_is_refused_and_left_alone(tmp_path, case, capsys):
    folder = tmp_path / "k"
    if case == "partial":
        keys.init(folder, 2)  # lacks uav3
    else:
        folder.mkdir()
        (folder / "notes.txt").write_text("mine")
    listing = sorted(p.name for p in folder.rglob("*"))
    with pytest.raises(ValueError, match="uav3" if case == "partial" else "no ca.pem"):
        prepare(folder, 3, [])
    assert main([str(folder), "--uavs", "3"]) == 2 and "REFUSED" in capsys.readouterr().err
    assert sorted(p.name for p in folder.rglob("*")) == listing


def test_role_sans_go_into_a_new_set_and_a_reused_set_without_them_is_warned_of(tmp_path, capsys):
    folder = tmp_path / "split"
    assert main([str(folder), "--uavs", "3", "--san", "gateway=172.30.0.1 uav1=172.30.0.1", "--san", ""]) == 0
    assert missing_sans(folder, ["172.30.0.1"]) == [] and missing_sans(folder, ["172.30.0.1"], role="uav1") == []
    assert missing_sans(folder, ["172.30.0.1"], role="uav2") == ["172.30.0.1"]
    what, warnings = prepare(folder, 3, [], sans={"gateway": ("172.30.0.1",), "uav2": ("10.9.9.9",)})
    assert what == "reused" and len(warnings) == 1 and "uav2's certificate does not name 10.9.9.9" in warnings[0]
    assert main([str(folder), "--san", "gateway=bad_name"]) == 2 and "neither" in capsys.readouterr().err


def test_an_older_set_without_the_tools_identities_is_enlarged_not_refused(tmp_path):
    import shutil

    folder = tmp_path / "older"
    keys.init(folder, 3)
    ca = (folder / "ca.pem").read_bytes()
    shutil.rmtree(folder / "web")
    shutil.rmtree(folder / "replay")
    what, warnings = prepare(folder, 3, [])
    assert what == "reused" and any("web" in w and "replay" in w for w in warnings), warnings
    assert (folder / "web" / "tls.pem").is_file() and (folder / "ca.pem").read_bytes() == ca
