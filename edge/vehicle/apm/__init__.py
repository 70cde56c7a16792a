"""Pure cores of the simulated ArduCopter (:mod:`edge.vehicle.mavsim` is their socket shell).

- :mod:`.params`   the parameter table and the MAVLink parameter protocol;
- :mod:`.streams`  the telemetry scheduler (SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM groups);
- :mod:`.missions` the mission protocol state machine for missions, fences and rally points;
- :mod:`.auto`     AUTO mode: walking the mission items;
- the mission-item conventions shared with the planner's exporters (capture id) are in
  :mod:`edge.geometry.ardupilot_items`;
- :mod:`.signing`  MAVLink 2 signing with the signature checked before the stream timestamp.

None of them opens a socket: each takes decoded values and returns ``(message, fields)``
pairs that the shell builds into pymavlink messages (:data:`edge.vehicle.mavsim.telemetry._CORE_MESSAGES`).
"""
