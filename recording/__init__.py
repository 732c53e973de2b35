"""Seeing a mission: the mission stream, the MCAP and rosbag2 sinks, the coordinator's recorder,
rebuilding a recording from mission.db. Defined here, where reading them loads nothing else (the
command lines' flags): the recording profiles."""

#: The MCAP profiles, the default first (docs/fleet.md, "mission.mcap").
PROFILES = ("foxglove", "ros2")
