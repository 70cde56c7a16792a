"""User-space network impairment for experiments (the kernel here has no ``netem`` qdisc).

DESIGN.md, "Running it": the launcher can put impairment proxies (delay, jitter, loss,
reordering, duplication, bandwidth, outage) on chosen links. Paper, Section 1: the system runs
over a 4G gateway, with UDP for sensing data, TCP for commands and RTP for imagery; these
proxies let the experiments reproduce such a link on one machine.

* :mod:`services.netem.model` — pure: :class:`~services.netem.model.Impairment` (what to do,
  parsed from a netem-like string) and :class:`~services.netem.model.Impairer` (the per-packet
  and per-chunk decisions, seeded, with counters).
* :mod:`services.netem.proxy` — :class:`~services.netem.proxy.UdpProxy` and
  :class:`~services.netem.proxy.TcpProxy`, real sockets, one per Zenoh link.
* :mod:`services.netem.schedule` — pure: the command grammar (``set SPEC``, ``cut [T]``,
  ``restore``, ``clear``, ``stats``) and schedule files (``at 25s cut 5s``) that change a
  running proxy's conditions.
* :mod:`services.netem.control` — the loopback UDP control channel of a running proxy
  (:class:`~services.netem.control.ControlServer`, :func:`~services.netem.control.send_control`).
* :mod:`services.netem.cli` — ``skynet netem udp|tcp --listen ... --target ... --impair ...
  [--schedule FILE] [--control HOST:PORT]`` and ``skynet netem ctl HOST:PORT COMMAND``.
"""

from services.netem.model import GilbertElliott, Impairer, Impairment
from services.netem.schedule import Command, ScheduleError, Step, load_schedule, parse_command, parse_schedule

__all__ = ["GilbertElliott", "Impairer", "Impairment", "Command", "ScheduleError", "Step", "load_schedule",
           "parse_command", "parse_schedule"]
