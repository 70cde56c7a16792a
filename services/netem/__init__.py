"""User-space network impairment for experiments (the kernel here has no ``netem`` qdisc).

Design notes: docs/experiments.md (services/netem/__init__.py).
"""

from services.netem.model import GilbertElliott, Impairer, Impairment
from services.netem.schedule import Command, ScheduleError, Step, load_schedule, parse_command, parse_schedule

__all__ = ["GilbertElliott", "Impairer", "Impairment", "Command", "ScheduleError", "Step", "load_schedule",
           "parse_command", "parse_schedule"]
