"""The ``skynet`` command: one subcommand per service or tool.

Design notes: docs/architecture.md (services/cli.py).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from protocol.textsafe import printable

#: subcommand -> (module, help line). The module's ``main(argv)`` receives the remaining args.
COMMANDS: dict[str, tuple[str, str]] = {
    "gateway": ("services.gateway.service", "run the gateway router relay (SkyNet <-> Internet)"),
    "edge": ("edge.board", "run one UAV's IoT board (vehicle driver, SkyNet, camera)"),
    "sim-autopilot": ("edge.vehicle.sim_autopilot", "simulated ArduCopters on MAVLink, for QGC, MAVProxy, MAVSDK"),
    "planner": ("services.planner.service", "run the planner RCU service (plan requests)"),
    "plan": ("services.planner.cli", "plan offline: compare algorithms, export missions, bench"),
    "detector": ("services.detector.service", "run the detector RCU service (imagery -> defects)"),
    "detect": ("services.detector.cli", "detect defects in images, evaluate on data sets"),
    "gcs": ("services.gcs.cli", "ground control station: run a mission over the bus"),
    "up": ("services.orchestration.launcher", "start the whole network on this machine"),
    "mission": ("services.orchestration.launcher", "start the network, run the default mission, write the report"),
    "netem": ("services.netem.cli", "user-space impairment proxy (UDP/TCP) for latency/loss experiments"),
    "bridge": ("services.orchestration.bridge", "forward a TCP port to a Unix socket or back (into a network namespace)"),
    "experiment": ("services.experiment.cli", "the mission over a grid of link loss/delay/jitter, with a table and plots"),
    "video": ("services.video.service", "every UAV's camera as standard RTP/UDP (H.264 or JPEG) with SDP files"),
    "web": ("services.web.service", "the live web page of the fleet (aiohttp, WebSocket)"),
    "report": ("services.gcs.journal", "the mission report again, from its log (mission.mcap) alone"),
    "replay": ("services.recording.replay", "play a recorded mission (MCAP) back onto the bus"),
    "demo": ("services.demo", "gateway + a demo publisher/subscriber pair, printing what flows"),
    "schema": ("protocol.contract", "print the wire contract: key space, link classes, envelope, JSON Schemas"),
    "keys": ("services.keys", "development fleet PKI: CA, per-node TLS certificates and signing keys"),
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: skynet <command> [options]", "", "commands:"]
    lines += [f"  {name:<{width}}  {help_}" for name, (_, help_) in COMMANDS.items()]
    return "\n".join(lines)


#: optional top-level import -> the extra of pyproject.toml that installs it
EXTRAS: dict[str, str] = {"pymavlink": "mavlink", "mavsdk": "mavsdk", "selenium": "browser",
                          "jax": "train", "optax": "train", "onnx": "train", "pyswarms": "bench"}


def missing_extra(exc: ModuleNotFoundError) -> str | None:
    """The one-line message for an optional dependency that is not installed, None for any other import error.

    >>> missing_extra(ModuleNotFoundError("No module named 'pymavlink'", name="pymavlink.dialects"))
    "needs the optional 'mavlink' extra (pymavlink is not installed): pip install -e '.[mavlink]'"
    >>> missing_extra(ModuleNotFoundError("No module named 'numpy'", name="numpy")) is None
    True
    """
    top = (exc.name or "").partition(".")[0]
    extra = EXTRAS.get(top)
    if extra is None:
        return None
    return f"needs the optional {extra!r} extra ({top} is not installed): pip install -e '.[{extra}]'"


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in {"-h", "--help", "help"}:
        print(usage())
        return 0
    name, rest = args[0], args[1:]
    if name not in COMMANDS:
        print(f"skynet: unknown command {name!r}\n\n{usage()}", file=sys.stderr)
        return 2
    try:
        module = importlib.import_module(COMMANDS[name][0])
        if name in {"up", "mission"}:
            return int(module.main([name, *rest]) or 0)
        return int(module.main(rest) or 0)
    except ModuleNotFoundError as exc:  # an optional extra this command needs: name it, no traceback
        message = missing_extra(exc)
        if message is None:
            raise
        print(f"skynet {name}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except RecursionError:  # a parser given input nested deeper than Python's stack (a crafted file)
        print(f"skynet {name}: error: input nested too deeply to read (recursion limit "
              f"{sys.getrecursionlimit()})", file=sys.stderr)
        return 2
    except Exception as exc:
        # bad input (a value, a file, an endpoint Zenoh refuses) is the user's to fix: say what, no traceback
        if isinstance(exc, (ValueError, OSError, argparse.ArgumentTypeError)) or type(exc).__name__ == "ZError":
            print(f"skynet {name}: error: {printable(exc)}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    raise SystemExit(main())
