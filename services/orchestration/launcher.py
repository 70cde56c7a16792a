"""The embedded default: the whole network on one machine, as separate processes on loopback.

Design notes: docs/architecture.md (services/orchestration/launcher.py).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

from protocol.bus import (
    Bus,
    BusConfig,
    BusOptions,
    config_from_args,
    multilink_endpoints,
    setup_logging,
    stop_event_on_signals,
)
from protocol.cliconfig import add_options, from_namespace
from protocol.links import LINK_LEASE_S
from protocol.readiness import notify_ready
from services import attach

from . import trustmode
from .config import MODELS, LaunchConfig, MissionLaunchConfig
from .faults import FaultInjector
from .plan import (
    HOST,
    CountingPorts,
    NetworkPlan,
    Plan,
    ProcessSpec,
    Trust,
    free_ports,
    make_plan,
    network_plan,
    own_speed_warning,
)
from .process import ProcessGroup
from .restart import RestartTracker
from .topology import CLASSES, open_timeout_ms

__all__ = ["Network", "Plan", "make_plan", "build_parser", "parse", "check", "main", "run", "run_mission",
           "SUPERVISOR_RESTART", "START_FAILED"]

#: what the mission's record calls a restart made by the launcher's supervisor, and a service that could not
#: start (``FaultRecord.action``; reported apart from injected faults, services.gcs.resilience)
SUPERVISOR_RESTART = "supervisor-restart"
START_FAILED = "start-failed"
#: how long a restarted service may take to come up (the gateway retries a busy port meanwhile)
RESTART_TIMEOUT_S = 30.0
#: a service that exits this many times in a row without ever coming up cannot start (not restarted again)
START_ATTEMPTS = 3
#: how long ``skynet mission`` waits for the requested services to come up before the flight, s
START_TIMEOUT_S = 90.0


class Network:
    """The processes of one run (its :class:`~.plan.NetworkPlan`), the proxies on its links, and their supervision.

    ``ground_station``: the run has an in-process GCS (``skynet mission``), whose uplink can be
    impaired. :meth:`kill`, :meth:`restart` and :meth:`link_proxies` are what the fault injector
    acts on.
    """

    #: services that stay in the machine's own namespace with --netns (what a user reaches from here)
    MAIN_NAMESPACE = ("web", "video")

    def __init__(self, config: LaunchConfig, echo=sys.stdout, ground_station: bool = False, plan: Plan | None = None):
        from protocol.scenario import load_scenario

        self.config = config
        self.ground_station = ground_station
        self.plan = plan or make_plan(config, ground_station)
        #: --netns: one network namespace per site (services.orchestration.netns), opened by start()
        self.ns = None
        self.group = ProcessGroup(echo=echo)
        #: link name -> {"tcp": TcpProxy, "udp": UdpProxy}, started by start()
        self.proxies: dict[str, dict] = {}
        #: TLS, certificate ACL, signed commands: secure by default, impaired or not (services.orchestration.trustmode)
        self.trust = trustmode.resolve(config, proxied=bool(self.plan.proxied))
        self.epoch = time.time() + 3.0
        self.tmp = Path(tempfile.mkdtemp(prefix="skynet-net-"))
        self.web_token: str | None = None
        if config.web and not ground_station:
            from services.web.server import TOKEN_ENV, new_token

            self.web_token = os.environ.get(TOKEN_ENV) or new_token()
        #: the whole network as data (:mod:`.plan`): every process, endpoint, identity and command line
        self.layout: NetworkPlan = network_plan(
            config, load_scenario(config.scenario),
            Trust.of(self.trust.keys, self.trust.tls), free_ports, ground_station=ground_station, epoch=self.epoch,
            workdir=str(self.tmp), web_token=self.web_token or "", checked=self.plan)
        #: the fleet-size defaults: the ground station's state feed, previews, the edges' priority
        self.load = self.layout.load
        #: the listen endpoints of each site's gateway (site 0: the ground station's)
        self.site_endpoints = self.layout.site_endpoints
        self.gateway_endpoints = self.site_endpoints[0]
        self.edge_endpoints: dict[int, list[str]] = {
            int(p.name[3:]): list(p.listens) for p in self.layout.processes if p.role == "edge"}
        self.injector: FaultInjector | None = None
        #: restarts the supervisor made: {"service", "code", "failures", "delay_s", "at"}
        self.restarts: list[dict] = []
        #: told of each restart (name, text); a mission sets its runner's ``note_fault`` here
        self.on_restart = None
        self._sup_stop = threading.Event()
        self._sup: threading.Thread | None = None
        #: the running network's description file (:meth:`describe`), None until written
        self.description: Path | None = None
        #: services that cannot start ({name: reason}, :meth:`start_failed`); told to ``on_start_failure``
        self.start_failures: dict[str, str] = {}
        self.on_start_failure = None

    # -- links
    def topology(self) -> list[str]:
        """One line per site: its gateway, where it listens and dials, and the nodes attached to it."""
        return self.layout.topology()

    def _start_proxies(self) -> None:
        """Start the plan's proxies (:class:`~.plan.ProxySpec`): a TLS pair (the default secure mode) gets two TCP
        proxies, the TLS session running end to end through them, so the link keeps its encryption, its
        certificates and the ACL; the best-effort class ("udp" in an impairment) is then a TLS stream too, where
        loss is retransmission delay."""
        from services.netem.proxy import TcpProxy, UdpProxy

        for spec in self.layout.proxies.values():
            pair = {}
            for cls, port, target, imp, seed, kind in zip(CLASSES, spec.ports, spec.targets, spec.impairments,
                                                          spec.seeds, ("tcp", spec.udp_kind)):
                pair[cls] = (TcpProxy if kind == "tcp" else UdpProxy)((HOST, port), target, imp, seed=seed).start()
            self.proxies[spec.link] = pair

    def _proxied_ends(self, link: str) -> list[str]:
        """The endpoints of ``link``'s proxies, TLS when its proxies are both TCP."""
        tp, up = self.proxies[link]["tcp"], self.proxies[link]["udp"]
        if up.kind == "tcp":
            return trustmode.tls_endpoints(HOST, tp.port, up.port)
        return multilink_endpoints(HOST, tp.port, up.port)

    def site_of(self, name: str) -> int:
        """The site whose gateway ``name`` attaches to: a UAV its formation's (``uavN``), an RCU (``planner``,
        ``detector``, ``detector-K``) its ``--rcu-site``, the ground station and the rest site 0."""
        try:
            return self.layout.get(name).site
        except KeyError:
            return 0

    def link_proxies(self, link: str) -> list:
        """The proxies of a link (TCP then UDP); KeyError if the link has none."""
        if link not in self.proxies:
            raise KeyError(f"link {link!r} has no proxies (proxied: {', '.join(sorted(self.proxies)) or 'none'})")
        return [self.proxies[link][c] for c in CLASSES]

    def proxy_stats(self) -> dict[str, dict[str, dict]]:
        return {link: {c: p.stats() for c, p in pair.items()} for link, pair in self.proxies.items()}

    def gcs_config(self) -> BusConfig:
        """The in-process ground station's session (mutual TLS with the key set's ``gcs`` identity)."""
        lease = {"lease": LINK_LEASE_S, "cfg": [("transport/unicast/open_timeout", json.dumps(
            open_timeout_ms(self.plan.impair.worst_delay_ms())))]} if self.plan.proxied else {}
        try:
            connect = list(self.layout.get("gcs").connects)
        except KeyError:  # skynet up: no ground station in the plan; a client of site 0's gateway
            connect = [trustmode.gateway_dial(e, self.trust.keys) for e in self.gateway_endpoints]
        keys = str(self.trust.keys) if self.trust.keys is not None and self.trust.tls else None
        return config_from_args(BusOptions(mode="client", connect=connect, multilink=True, keys=keys, **lease), "gcs")

    def gcs_signer(self):
        """The ground station's signer (None: --insecure, unsigned commands)."""
        if self.trust.keys is None:
            return None
        from protocol.keyset import KeySet
        return KeySet(self.trust.keys, "gcs").signer()

    def plan_verifier(self):
        """The ground station's verifier of the planner's signed plans (None without a key set)."""
        if self.trust.keys is None:
            return None
        from services.gcs.cli import plan_verifier_of
        return plan_verifier_of(self.trust.keys)

    # -- services
    def prefix_of(self, name: str) -> list[str]:
        """The command that runs ``name`` in its site's namespace (--netns), else none."""
        try:
            ns = self.layout.get(name).namespace
        except KeyError:
            ns = None if name in self.MAIN_NAMESPACE else self.site_of(name)
        if self.ns is None or ns is None:
            return []
        return self.ns.prefix(ns)

    def start_process(self, spec: ProcessSpec):
        """Start one process of the plan; one the plan says to wait for (gateway, namespace proxy or bridge) must
        signal it is up within 30 s, else RuntimeError with its last lines."""
        svc = self.group.start(spec.name, list(spec.argv), prefix=self.prefix_of(spec.name), ready=spec.ready,
                               env=spec.env or None)
        if spec.wait and not svc.wait_ready(30):
            raise RuntimeError(f"{spec.name} did not start:\n" + "\n".join(svc.lines[-20:]))
        return svc

    def start(self) -> None:
        launcher_log = logging.getLogger("skynet.launcher")
        for w in self.trust.warnings:
            launcher_log.warning("%s", w)
        for path, text in self.layout.files.items():
            Path(path).write_text(text)
            Path(path).chmod(0o600)
        self._start_proxies()
        if self.config.netns:
            from .netns import Namespaces, available

            ok, why = available()
            if not ok:
                raise RuntimeError(f"--netns: no network namespaces here: {why}")
            self.ns = Namespaces(self.plan.sites).open()
        said = False
        for spec in self.layout.processes:
            if spec.in_process:
                continue
            if spec.role not in ("gateway", "link", "bridge") and not said:
                said = True
                if len(self.site_endpoints) > 1:
                    for line in self.topology():
                        launcher_log.info("%s", line)
                if self.load.chosen:
                    launcher_log.info("%d UAVs on one machine: %s", self.config.uavs, "; ".join(self.load.chosen))
            self.start_process(spec)

    def web_url(self) -> str | None:
        """The URL of the page ``skynet up --web`` started, with its token (None without a page)."""
        from services.web.server import page_url, parse_listen

        return None if self.web_token is None else page_url(*parse_listen(self.config.web), self.web_token)

    def start_faults(self, log: logging.Logger) -> FaultInjector | None:
        """The fault injector of ``--fault`` (None without faults), not started yet: ``start(origin)``
        with the wall time AT counts from, or ``attach(runner)`` then ``start()``."""
        if not self.plan.faults:
            return None
        self.injector = FaultInjector(self, self.plan.faults, log)
        return self.injector

    def kill(self, name: str) -> None:
        """SIGKILL a service (a crash)."""
        self.group.kill(name)

    def restart(self, name: str) -> float:
        """Start a killed service again with the same command line (same ports); the seconds until it
        signalled it is up. The gateway's ports may still be held for a moment: it is retried until
        :data:`RESTART_TIMEOUT_S`."""
        t0 = time.monotonic()
        while True:
            svc = self.group.restart(name)
            left = RESTART_TIMEOUT_S - (time.monotonic() - t0)
            if svc.wait_ready(max(left, 0.1)):
                return time.monotonic() - t0
            if svc.alive() or time.monotonic() - t0 > RESTART_TIMEOUT_S:
                raise RuntimeError(f"{name} did not come back up:\n" + "\n".join(svc.lines[-10:]))
            time.sleep(0.2)  # it exited (e.g. its port still busy): try again

    def check_alive(self) -> list[str]:
        """Services that ended on their own (not those a fault killed)."""
        return [s.name for s in self.group.services if not s.alive() and not s.killed]

    def start_supervisor(self, log: logging.Logger, tracker: RestartTracker | None = None,
                         period_s: float = 0.2) -> None:
        """Restart services that end by themselves (see the module docstring), in a thread until :meth:`stop`."""
        tracker = tracker or RestartTracker()

        def loop() -> None:
            while not self._sup_stop.wait(period_s):
                try:
                    self.supervise(tracker, log)
                except Exception:  # the supervisor outlives a failed pass, and says so
                    log.exception("supervisor pass failed")

        self._sup = threading.Thread(target=loop, name="supervisor", daemon=True)
        self._sup.start()

    def supervise(self, tracker: RestartTracker, log: logging.Logger) -> None:
        """One pass: schedule the restart of services that ended on their own, start those that are due."""
        if self.group.closed:
            return
        now = time.monotonic()
        for svc in list(self.group.services):
            if svc.alive() or svc.killed or tracker.pending(svc.name) or svc.name in self.start_failures:
                continue
            if svc.ready and not svc.ever_ready and svc.restarts + 1 >= START_ATTEMPTS:
                self.start_failed(svc.name, f"exited {svc.restarts + 1} times without coming up, last with code "
                                            f"{svc.proc.returncode}: {svc.reason()}", log)
                continue
            p = tracker.exited(svc.name, now, now - svc.started, svc.proc.returncode)
            how = "before it came up" if svc.ready and not svc.ever_ready else f"after {now - svc.started:.1f} s"
            log.error("%s exited with code %s %s (%s); restarting it in %.1f s (quick failure %d in a row)",
                      svc.name, p.code, how, svc.reason(), p.due - now, p.failures)
        for p in tracker.due(now):
            try:
                svc = self.group.restart(p.name)
            except RuntimeError:  # the group is stopping
                return
            text = f"exited with code {p.code}; restarted by the supervisor (run {svc.restarts + 1})"
            self.restarts.append({"service": p.name, "code": p.code, "failures": p.failures,
                                  "at": time.time(), "text": text})
            log.warning("%s %s", p.name, text)
            if self.on_restart is not None:
                self.on_restart(p.name, text)

    def describe(self) -> Path | None:
        """Leave the running network's description where the tools find it (:mod:`.attach`); removed by
        :meth:`stop`. A folder it cannot be written to is said, not fatal (None): the tools then need ``-e``."""
        path = attach.network_path(self.config.network)
        desc = attach.describe(self.config.fleet, self.gateway_endpoints, self.trust.keys, self.trust.tls)
        try:
            self.description = attach.write(path, desc)
        except OSError as exc:
            logging.getLogger("skynet.launcher").warning(
                "could not describe the network in %s (%s): skynet web/video/replay need -e %s", path,
                exc.strerror or exc, " -e ".join(self.gateway_endpoints))
        return self.description

    def start_failed(self, name: str, reason: str, log: logging.Logger | None = None) -> None:
        """Note that ``name`` cannot start (not restarted again): :attr:`start_failures`, the log, the hook."""
        if name in self.start_failures:
            return
        self.start_failures[name] = reason
        (log or logging.getLogger("skynet.launcher")).error("%s did not start: %s", name, reason)
        if self.on_start_failure is not None:
            self.on_start_failure(name, reason)

    def wait_started(self, names: list[str], timeout_s: float, log: logging.Logger | None = None) -> dict[str, str]:
        """Wait until each of ``names`` came up or cannot start (the supervisor decides, :meth:`supervise`),
        at most ``timeout_s``; one still not up then cannot start either. The failures ({name: reason})."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self.group.closed:
            pending = [n for n in names if n not in self.start_failures and not self.group.get(n).ever_ready]
            if not pending:
                break
            time.sleep(0.2)
        for n in names:
            if n not in self.start_failures and not self.group.get(n).ever_ready:
                self.start_failed(n, f"not up after {timeout_s:.0f} s ({self.group.get(n).reason()})", log)
        return {n: self.start_failures[n] for n in names if n in self.start_failures}

    def supervised(self) -> list[str]:
        """The processes that signal when they are up (every one the plan starts but the sim autopilots)."""
        return [s.name for s in self.group.services if s.ready]

    def all_up(self) -> bool:
        """Every process that signals readiness has come up at least once."""
        return all(s.ever_ready for s in self.group.services if s.ready)

    def requested(self) -> list[str]:
        """The services a run asks for besides the edges: planner, detector(s), and video / web when asked."""
        n = self.config.detectors
        out = ["planner", *(["detector"] if n == 1 else [f"detector-{k}" for k in range(n)])]
        if self.config.video:
            out.append("video")
        if self.config.web and not self.ground_station:
            out.append("web")
        return out

    def stop(self) -> dict:
        if self.description is not None:
            attach.remove(self.description)
            self.description = None
        self._sup_stop.set()
        if self._sup is not None:
            self._sup.join(5.0)
        if self.injector is not None:
            self.injector.cancel()  # then the group refuses restarts and its stop ends a restart's wait
        codes = self.group.stop()
        if self.injector is not None:
            self.injector.stop()
        for pair in self.proxies.values():
            for p in pair.values():
                p.stop()
        if self.ns is not None:
            self.ns.close()
        shutil.rmtree(self.tmp, ignore_errors=True)
        return codes


def build_parser(prog: str) -> argparse.ArgumentParser:
    """``skynet up`` or ``skynet mission``: the options of its :data:`.config.MODELS`."""
    p = argparse.ArgumentParser(prog=f"skynet {prog}", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="Links: uavN, planner, detector" + (", gcs" if prog == "mission" else "")
                                + " (uplinks to the gateway), uavI-uavJ (SkyNet), uplinks, skynet, all.\n"
                                "Examples:\n"
                                '  --impair "all/udp=after 2s delay 200ms loss 20%"\n'
                                '  --impair uav2="delay 50ms jitter 10ms"   --impair uav1-uav2=loss 5%\n'
                                '  --fault "20s kill gateway for 3s"   --fault "15s cut uplinks for 8s"\n'
                                '  --fault "25s kill uav3"   --fault "15s partition uav1-uav2 for 10s"')
    return add_options(p, MODELS[prog])


def parse(prog: str, argv: list[str]) -> LaunchConfig:
    """The options of ``skynet PROG ARGV``; a bad one is argparse's one-line error (SystemExit 2)."""
    parser = build_parser(prog)
    return from_namespace(MODELS[prog], parser.parse_args(argv), parser)


def check(config: LaunchConfig) -> tuple[Plan, NetworkPlan]:
    """The run checked before anything starts: links, faults, sites (:func:`.plan.make_plan`), the scenario, and
    every service's own config, in the network the run would start (what ``--dry-run`` prints: ports numbered from
    7447, the key set named, not made). ValueError with a one-line message."""
    from protocol.scenario import ScenarioError, load_scenario

    plan = make_plan(config, ground_station=(mission := isinstance(config, MissionLaunchConfig)))
    try:
        scenario = load_scenario(config.scenario)
    except ScenarioError as e:
        raise ValueError(f"--scenario: {e}") from None
    keys_dir = trustmode.planned_keys(config)
    if isinstance(config, MissionLaunchConfig):
        config = config.model_copy(update={"save_frames": str(Path(config.out or "reports/mission-<time>") / "frames")})
    return plan, network_plan(config, scenario, Trust.of(keys_dir, keys_dir is not None), CountingPorts(7447),
                              ground_station=mission, epoch=0.0, workdir="<run>", web_token="<random>", checked=plan)


def main(argv: list[str] | None = None) -> int:
    """``skynet up|mission``: parse and check the command line, then :func:`run` it."""
    argv = list(sys.argv[1:] if argv is None else argv)
    prog = argv.pop(0) if argv and argv[0] in MODELS else "up"
    config = parse(prog, argv)
    try:
        checked = check(config)
    except ValueError as e:  # one line, as the other commands' bad input (services.cli)
        from protocol.textsafe import printable

        print(f"skynet {prog}: error: {printable(e)}", file=sys.stderr)
        return 2
    return run(config, checked)


def run(config: LaunchConfig, checked: tuple[Plan, NetworkPlan] | None = None) -> int:
    """``--dry-run``: print the plan (a table, or JSON with ``--json``); else start the network (``skynet up``), or
    the network and its mission (``skynet mission``)."""
    plan, layout = checked or check(config)
    if config.dry_run:
        print(json.dumps(layout.to_json(), indent=1) if config.as_json else layout.table())
        return 0
    mission = isinstance(config, MissionLaunchConfig)
    log = setup_logging("mission" if mission else "up")
    if config.autopilot and config.speed != 1.0:
        log.warning("%s", own_speed_warning(config.speed))
    stop = stop_event_on_signals()
    if mission:
        return run_mission(config, log, stop, plan)
    net = Network(config, plan=plan)
    try:
        net.start()
        log.info("network up: gateway at %s; Ctrl-C to stop", " ".join(net.gateway_endpoints))
        if net.web_url():
            log.info("web page at %s", net.web_url())
        for link in sorted(net.proxies):
            log.info("proxies on %s: tcp %s, udp %s", link, *(net.proxies[link][c].port for c in CLASSES))
        injector = net.start_faults(log)
        if injector is not None:
            injector.start(origin=time.time())
        net.start_supervisor(log)  # a service that ends is restarted, the network stays up
        described = net.describe()
        if described is not None:
            log.info("network described in %s: `skynet web`, `skynet video`, `skynet replay FILE` attach to it "
                     "from this folder with no options", described)
        announced = False
        while not stop.wait(1.0 if announced else 0.2):
            if not announced and net.all_up():
                announced = True  # the launcher's own ready signal: every service it started is up
                log.info("all services up: %s", " ".join(net.supervised()))
                notify_ready("launcher", "up")
    finally:
        codes = net.stop()
        log.info("stopped: %s", codes)
    return 0


def run_mission(config: MissionLaunchConfig, log: logging.Logger, stop, plan: Plan | None = None) -> int:
    from protocol.scenario import load_scenario
    from services.gcs.cli import run_mission as gcs_mission
    from services.gcs.mission import MissionOptions
    from services.recording.record import check_output_folder

    # not writable or too little room: refused (RecordingError) before any service starts
    out = check_output_folder(config.out or f"reports/mission-{time.strftime('%Y%m%d-%H%M%S')}")
    log_file = open(out / "services.log", "w")
    # the deliverable's captures come through the bus into the mission log; the detector keeps its own copies only
    # for the live page's deduplicated defect count (services.web.tally)
    config = config.model_copy(update={"save_frames": str((out / "frames").resolve()) if config.web else None})
    net = Network(config, echo=log_file, ground_station=True, plan=plan)
    scenario = load_scenario(config.scenario)
    try:
        net.start()
        net.describe()
        cfg = net.gcs_config()
        hooks_signer = net.gcs_signer()
        # every edge imports and starts at once on the same cores: 48 of them took over 30 s to appear
        options = MissionOptions(uavs=tuple(range(1, config.uavs + 1)), algorithm=config.algorithm, seed=config.seed,
                                 speed=config.speed, appear_timeout_s=max(30.0, 2.5 * config.uavs),
                                 ready_timeout_s=config.ready_timeout, method=config.method)
        injector = net.start_faults(log)

        def on_runner(runner) -> None:
            net.on_restart = lambda name, text: runner.note_fault(SUPERVISOR_RESTART, name, text)

            def start_failure(name: str, reason: str) -> None:
                runner.note_fault(START_FAILED, name, reason)
                with runner._lock:
                    runner.record.failures.append(f"{name} did not start: {reason}")

            for r in list(net.restarts):  # made before the runner was (while the services came up)
                runner.note_fault(SUPERVISOR_RESTART, r["service"], r["text"])
            for name, reason in dict(net.start_failures).items():
                start_failure(name, reason)
            net.on_start_failure = start_failure
            # the services asked for, before the flight; the runner listens already (the edges' first events)
            failed = net.wait_started(net.requested(), START_TIMEOUT_S + 2.0 * config.uavs, log)
            if failed:
                log.error("the mission will fail: %s", "; ".join(f"{n} did not start ({r})" for n, r in failed.items()))
            if injector is not None:
                injector.attach(runner)
                injector.start()

                def not_injected() -> str | None:  # a run that ends before a fault it was asked for is not that run
                    missed = injector.finish()
                    return "never injected, the mission ended first: " + "; ".join(missed) if missed else None

                runner.closing.append(not_injected)

        hooks = {"on_runner": on_runner}
        net.start_supervisor(log)
        with Bus(cfg, fleet=config.fleet, name="gcs") as bus:
            web_server = None
            if config.web:  # the live page in the ground station's process, with its plan (services.web)
                from services.web.service import follow_runner, start_web

                view, web_server = start_web(bus, config.web, scenario, log=log, frames=config.save_frames)
                before = hooks.get("on_runner")
                hooks["on_runner"] = lambda runner: (before and before(runner),
                                                     follow_runner(view, runner, tally=web_server.tally))
            try:
                code = gcs_mission(bus, scenario, options, str(out), config.quiet, log, abort=stop,
                                   ground_truth=config.camera == "synthetic", signer=hooks_signer,
                                   plan_verifier=net.plan_verifier(),
                                   record=not config.no_record, **hooks)
            finally:
                if web_server is not None:
                    web_server.stop()
        if net.proxies:
            (out / "proxies.json").write_text(json.dumps(net.proxy_stats(), indent=1))
        if net.restarts:
            (out / "restarts.json").write_text(json.dumps(net.restarts, indent=1))
    finally:
        net.stop()
        log_file.close()
    log.info("services' logs: %s", out / "services.log")
    from services.inspection.mission import deliverable_line

    line = deliverable_line(out)  # the last line: what was found, and where the inspector's report is
    if line:
        log.info("inspection: %s", line)
    return code
