"""The mission as a ROS 2 graph over Zenoh, in rmw_zenoh's own key space (docs/fleet.md, "ROS 2").

Nothing here is imported unless a process runs with ``--ros2`` / ``--ros2-robot`` or records the
``ros2`` MCAP profile; no ROS installation is needed (the formats are written by hand and tested
against rmw_zenoh's source and against PyPI's ``rosbags``).

* :mod:`ros2.rmw` — rmw_zenoh's formats: data keys, liveliness tokens and their QoS field, the
  attachment of every sample, GIDs, the check for peers of another ROS distribution;
* :mod:`ros2.msgs` — the standard message types used (field tables, RIHS01 hashes) and their CDR
  encoding and decoding;

Target: **ROS 2 Jazzy and later** (rmw_zenoh_cpp 0.2 and later, built on Zenoh 1.x; Kilted and
Rolling use the same formats). Humble's rmw_zenoh (24-byte GIDs, no type hashes) is detected and
refused with one line (:func:`ros2.rmw.parse_token`, :func:`ros2.rmw.parse_attachment`).
"""

#: The ROS 2 distribution whose rmw_zenoh formats this package writes (and later ones).
DISTRO = "jazzy"
