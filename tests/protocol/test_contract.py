"""The published wire contract: the document is current, and what it promises is on the wire."""

import json
import subprocess
import sys
from pathlib import Path

import msgpack
import zenoh

from protocol import codec, contract, keys
from protocol.messages import MESSAGE_TYPES
from tests.conftest import spawn_node, wait_until

FLEET = "test"
DOC = Path(__file__).resolve().parents[2] / "docs" / "wire-contract.md"


def test_the_document_is_current():
    assert DOC.read_text() == contract.document() + "\n", \
        "docs/wire-contract.md is stale: regenerate it with `skynet schema > docs/wire-contract.md`"


def test_every_message_type_has_a_schema_and_every_example_is_valid():
    schemas = contract.schemas()
    assert set(schemas) == set(MESSAGE_TYPES)
    for tag, schema in schemas.items():
        assert schema["type"] == "object" and schema["additionalProperties"] is False, tag
    for tag in contract.EXAMPLES:
        msg = contract.example(tag)
        assert codec.decode(codec.encode(msg)) == msg


def test_every_key_of_the_contract_parses_as_a_key_of_the_key_space():
    for spec in contract.key_space():
        concrete = spec.pattern.replace("<fleet>", "f1").replace("<id>", "7").replace("<name>", "planner")
        info = keys.parse(concrete)
        assert info.topic == spec.topic


def test_skynet_schema_prints_the_document_json_and_one_schema():
    run = lambda *a: subprocess.run([sys.executable, "-m", "services.cli", "schema", *a], capture_output=True,
                                    text=True, timeout=60)
    doc = run()
    assert doc.returncode == 0 and doc.stdout == contract.document() + "\n"
    whole = json.loads(run("--json").stdout)
    assert whole["envelope"]["encoding"] == "application/msgpack;skynet/1/<type>"
    assert {k["key"] for k in whole["keys"]} >= {"skynet/<fleet>/uav/<id>/state", "skynet/<fleet>/uav/<id>/cmd"}
    one = json.loads(run("state").stdout)
    assert "pos" in one["properties"]
    bad = run("nope")
    assert bad.returncode == 2 and "unknown message type" in bad.stderr


def test_a_generic_zenoh_client_reads_the_encoding_of_samples_and_replies(gateway):
    """A plain zenoh-python client (no project code) sees the encoding of a state and of command replies."""
    node = spawn_node(f"""
import time
from protocol import keys
from protocol.bus import Bus, BusConfig, Rejected
from protocol.links import TELEMETRY
from protocol.messages import *
bus = Bus(BusConfig(mode="peer", connect={gateway!r}, listen=["tcp/127.0.0.1:0"], multilink=True), "{FLEET}", "p")
def handle(cmd):
    if isinstance(cmd, Land):
        raise Rejected("not now", "busy")
    return CommandAck(uav=3, cmd_id=cmd.cmd_id, accepted=True)
bus.serve(keys.cmd("{FLEET}", 3), handle)
pub = bus.publisher(keys.state("{FLEET}", 3), TELEMETRY)
print("ready", flush=True)
for i in range(300):
    pub.put(VehicleState(uav=3, seq=i, t=i*0.05, stamp=time.time(), pos=(1,2,3), vel=(0,0,0), att=(0,0,0),
                         rates=(0,0,0), mode="hold"))
    time.sleep(0.05)
bus.close()
""")
    try:
        assert node.stdout.readline().strip() == "ready"
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([gateway[0].split("?")[0]]))
        seen = []
        with zenoh.open(conf) as s:
            s.declare_subscriber(f"skynet/{FLEET}/uav/3/state", lambda smp: seen.append(str(smp.encoding)))
            assert wait_until(lambda: seen, 20), "no state sample"
            assert seen[0] == "application/msgpack;skynet/1/state"

            def ask(body):
                payload = msgpack.packb([1, body["kind"] and f"cmd.{body['kind']}", body])
                for r in s.get(f"skynet/{FLEET}/uav/3/cmd", payload=payload, timeout=5):
                    return r
            ok = ask({"uav": 3, "cmd_id": 1, "kind": "hold"})
            assert ok.ok is not None and str(ok.ok.encoding) == "application/msgpack;skynet/1/cmd.ack"
            refused = ask({"uav": 3, "cmd_id": 2, "kind": "land"})
            assert refused.err is not None and str(refused.err.encoding) == "application/msgpack;skynet/1/error"
            assert msgpack.unpackb(refused.err.payload.to_bytes())[2]["reason"] == "not now"
    finally:
        node.kill()
        node.communicate(timeout=10)
