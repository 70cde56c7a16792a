"""The planner service's typed configuration (``skynet planner``)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from protocol.bus import BusMode, BusOptions
from protocol.cliconfig import Cli

from .limits import TIME_BUDGET_S


class PlannerConfig(BusOptions):
    """The options of the planner RCU."""

    mode: BusMode = "client"
    time_budget: Annotated[float, Cli(flag="--time-budget-s", metavar="S")] = Field(
        default=TIME_BUDGET_S, gt=0.0, le=86400.0,
        description="longest a plan request may take, s; then it is answered 'timeout' (services.planner.limits)")
    anytime: bool = Field(default=False, description="when the time budget runs out, answer with the best "
                                                     "collision-free path found so far")
