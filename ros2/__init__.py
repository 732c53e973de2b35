"""The mission as a ROS 2 graph over Zenoh, in rmw_zenoh's own key space (docs/fleet.md, "ROS 2").

Nothing here is imported unless a process runs with ``--ros2`` / ``--ros2-robot`` or records the
``ros2`` MCAP profile; no ROS installation is needed (the formats are written by hand and tested
against rmw_zenoh's source and against PyPI's ``rosbags``).

* :mod:`ros2.rmw` — rmw_zenoh's formats: data keys, liveliness tokens and their QoS field, the
  attachment of every sample, GIDs, the check for peers of another ROS distribution;
* :mod:`ros2.msgs` — the standard message types used (field tables, RIHS01 hashes) and their CDR
  encoding and decoding;
* :mod:`ros2.graph` — a ROS 2 node on a zenoh session: its liveliness tokens, publishers and
  subscriptions;
* :mod:`ros2.topics` — the mission stream (recording.stream) as ROS 2 messages: one home for topic
  names, types, QoS and message contents, shared by the live publisher and the bag writer;
* :mod:`ros2.publisher` — the coordinator's and the carriers' ROS 2 nodes (``--ros2``);
* :mod:`ros2.bag` — the ``ros2`` MCAP profile (a rosbag2 bag, via ``rosbags``);
* :mod:`ros2.robot` — a real ROS 2 robot as a carrier's body (``--ros2-robot``).

Target: **ROS 2 Jazzy and later** (rmw_zenoh_cpp 0.2 and later, built on Zenoh 1.x; Kilted and
Rolling use the same formats). Humble's rmw_zenoh (24-byte GIDs, no type hashes) is detected and
refused with one line (:func:`ros2.rmw.parse_token`, :func:`ros2.rmw.parse_attachment`).
"""

#: The ROS 2 distribution whose rmw_zenoh formats this package writes (and later ones).
DISTRO = "jazzy"
