"""MAVLink vehicle driver: an autopilot behind :class:`~edge.vehicle.driver.VehicleDriver`, split by concern.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/__init__.py).
"""

from edge.vehicle.apm.modes import CopterMode

from .commands import CommandRefused, VehicleLinkError, command_name, result_name
from .dialect import ARDUCOPTER, Dialect, copter_mode, copter_mode_name
from .driver import MavlinkDriver, MavlinkParams
from .guided import TYPE_MASK_POS_VEL_ACC_YAW, TYPE_MASK_POS_VEL_YAW, TYPE_MASK_POS_YAW
from .handlers import attitude_ned_to_enu, enu_to_ned, ned_to_enu, rates_frd_to_flu, yaw_enu_to_ned, yaw_ned_to_enu
from .link import open_connection
from .phase import Phase
from .progress import MissionProgress

__all__ = ["CopterMode", "MavlinkParams", "MavlinkDriver", "VehicleLinkError", "CommandRefused", "Phase", "Dialect",
           "ARDUCOPTER", "TYPE_MASK_POS_VEL_YAW", "TYPE_MASK_POS_VEL_ACC_YAW", "TYPE_MASK_POS_YAW", "copter_mode",
           "copter_mode_name", "ned_to_enu", "enu_to_ned", "yaw_ned_to_enu", "yaw_enu_to_ned", "attitude_ned_to_enu",
           "rates_frd_to_flu", "open_connection", "result_name", "command_name", "MissionProgress"]
