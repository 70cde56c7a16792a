"""``skynet demo``: the gateway plus a demo publisher/subscriber pair, printing what flows.

Design notes: docs/architecture.md (services/demo.py).
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

from protocol import keys
from protocol.bus import Bus, BusConfig, multilink_endpoints
from protocol.cliconfig import show_defaults
from protocol.links import TELEMETRY
from protocol.messages import CommandAck, Hold, Message, Mode, VehicleState
from services.orchestration.process import ProcessGroup, free_port_pair


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="skynet demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=10, help="messages each way")
    parser.add_argument("--fleet", default=keys.DEFAULT_FLEET, help="fleet name (key space prefix)")
    args = show_defaults(parser).parse_args(argv)
    tcp, udp = free_port_pair()
    endpoints = multilink_endpoints("127.0.0.1", tcp, udp)
    with ProcessGroup() as group:
        gw = group.start("gateway", ["gateway", "--fleet", args.fleet, *sum((["--listen", e] for e in endpoints), []),
                                     "--multilink"], ready=True)
        if not gw.wait_ready():
            print("gateway did not start")
            return 1
        peer_cfg = BusConfig(mode="peer", connect=endpoints, listen=["tcp/127.0.0.1:0"], multilink=True)
        client_cfg = BusConfig(mode="client", connect=endpoints, multilink=True)
        with Bus(peer_cfg, args.fleet, "uav1") as uav, Bus(client_cfg, args.fleet, "gcs") as gcs:
            received: list[Message] = []

            def on_state(msg: Message, sample: Any) -> None:
                received.append(msg)
                assert isinstance(msg, VehicleState)
                print(f"gcs <- {sample.key_expr}: seq={msg.seq} pos=({msg.pos[0]:.1f}, {msg.pos[1]:.1f}, "
                      f"{msg.pos[2]:.1f}) age={1000 * (time.time() - msg.stamp):.2f} ms")

            gcs.subscribe(keys.state(args.fleet, "*"), on_state, expect=VehicleState, link=TELEMETRY)
            uav.serve(keys.cmd(args.fleet, 1), lambda m: CommandAck(uav=1, cmd_id=getattr(m, "cmd_id", 0),
                                                                    accepted=True, reason=f"{getattr(m, 'kind', '?')} ok"))
            time.sleep(0.5)
            pub = uav.publisher(keys.state(args.fleet, 1), TELEMETRY)
            for i in range(args.count):
                a = i / 5
                pub.put(VehicleState(uav=1, seq=i, t=i * 0.1, stamp=time.time(), pos=(10 * math.cos(a), 10 * math.sin(a), 30),
                                     vel=(0, 0, 0), att=(0, 0, a), rates=(0, 0, 0), mode=Mode.HOLD, armed=True))
                time.sleep(0.1)
            reply = gcs.request(keys.cmd(args.fleet, 1), Hold(uav=1, cmd_id=1), expect=CommandAck)
            print(f"gcs -> uav1 hold: ok={reply.ok} ack={reply.message} in {1000 * reply.elapsed_s:.2f} ms")
            missing = gcs.request(keys.cmd(args.fleet, 9), Hold(uav=9, cmd_id=2), expect=CommandAck, timeout=1.0)
            print(f"gcs -> uav9 hold: ok={missing.ok} ({missing.error})")
            for link in uav.links():
                print(f"uav1 link: {link.src} -> {link.dst} reliability={link.reliability}")
            ok = len(received) > 0 and reply.ok and not missing.ok
            print(f"demo {'ok' if ok else 'FAILED'}: {len(received)}/{args.count} states received")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
