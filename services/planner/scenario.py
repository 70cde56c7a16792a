"""The planner's scenario: the typed model and its TOML loader live in :mod:`protocol.scenario`.

The planner's modules import the scenario's names from here (one import line each); nothing is
defined here.
"""

from protocol.scenario import (  # noqa: F401
    Bounds,
    Camera,
    CostSpec,
    Cylinder,
    FormationSpec,
    Inspection,
    Origin,
    PlannerSpec,
    Scenario,
    ScenarioError,
    Speeds,
    Surface,
    default_scenario_path,
    load_scenario,
    validate_scenario,
)
