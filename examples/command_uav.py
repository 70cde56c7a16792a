"""Send one signed command to one UAV and print its acknowledgement.

The ground station's way (services/gcs/commands.py): the command goes in an Ed25519 envelope signed
with the key set's `gcs` signing key and addressed to the UAV's command key (protocol/signing.py);
the UAV verifies it, runs it or refuses it, and answers with a CommandAck. Beside `skynet up`::

    python examples/command_uav.py --uav 1 --command hold     # a UAV on the ground refuses: not airborne
    python examples/command_uav.py --uav 1 --command resume

Exit status 0 when the UAV accepted the command, 1 otherwise (refused, no answer, cannot attach).
"""

from __future__ import annotations

import argparse
import sys
import time

from protocol import keys
from protocol.cliconfig import add_options
from protocol.keyset import KeySet
from protocol.messages import CommandAck, Hold, Land, Resume, ReturnToLaunch
from protocol.textsafe import printable
from services.attach import AttachOptions, open_bus

ROLE = "gcs"  # the only identity the UAVs take commands from (the key set's trust/ folder)
COMMANDS = {"hold": Hold, "resume": Resume, "land": Land, "rtl": ReturnToLaunch}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(parser, AttachOptions)
    parser.add_argument("--uav", type=int, default=1, help="the UAV's id (default: %(default)s)")
    parser.add_argument("--command", choices=sorted(COMMANDS), default="hold", help="(default: %(default)s)")
    parser.add_argument("--timeout-s", dest="timeout", type=float, default=2.0, help="wait this long for the answer, s (default: %(default)s)")
    args = parser.parse_args(argv)
    try:
        bus = open_bus(args, ROLE, sys.argv[1:] if argv is None else argv, name="command-uav")
        with bus:
            signer = KeySet(args.keys, ROLE).signer() if args.keys else None  # None: an --insecure network
            cmd = COMMANDS[args.command](uav=args.uav, cmd_id=int(time.time()) % 2**31)
            key = keys.cmd(args.fleet, args.uav)
            reply = bus.request(key, cmd if signer is None else signer.sign(cmd, key), expect=CommandAck,
                                timeout=args.timeout)
    except (ValueError, OSError) as exc:  # cannot attach, not a key set, no signing key: one line
        parser.exit(1, f"{parser.prog}: error: {exc}\n")
    except KeyboardInterrupt:
        return 1
    ack = reply.message
    if not reply.ok or not isinstance(ack, CommandAck) or (ack.uav, ack.cmd_id) != (args.uav, cmd.cmd_id):
        print(f"uav {args.uav}: no acknowledgement of {args.command} #{cmd.cmd_id}: {printable(reply.error)}")
        return 1
    verdict = "accepted" if ack.accepted else f"refused: {printable(ack.reason)}"
    print(f"uav {ack.uav} acknowledged {args.command} #{ack.cmd_id} in {reply.elapsed_s * 1000:.0f} ms: {verdict}")
    return 0 if ack.accepted else 1


if __name__ == "__main__":
    sys.exit(main())
