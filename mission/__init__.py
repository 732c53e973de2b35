"""PURE: the mission state machines of the fleet.

* :mod:`mission.events` — the coordinator's events (Hello, Observation, liveliness, decision,
  confirmation, Bye, end), with the time they happened as data;
* :mod:`mission.state` — :class:`~mission.state.MissionState` and
  ``step(state, event) -> (state, effects)``: every mission rule (stale, future, duplicate,
  unknown carrier, no Hello, fingerprint refusal, ...). Live handling and recovery from
  mission.db are the same fold;
* :mod:`mission.summary` — summary.json as a function of the state;
* :mod:`mission.report` — the report's merge of mission.db's events and the carriers' logs, by
  the same fold;
* :mod:`mission.carrier` — the carrier's side: which stage it is at, decisions handled at most
  once with their first answer, late / idle / already, resynchronisation from State;
* :mod:`mission.timeouts` — every timeout default;
* :mod:`mission.timers` — every timer rule, a pure function of what is known and the time.

Nothing here imports zenoh, msgpack, sqlite3 or pymunk, and nothing does I/O or reads a clock:
the processes (coordinator/node.py, carriers/node.py) move bytes, keep time and persist.
"""
