"""The stores of a mission: their SQLite schemas, writers and readers, in one place.

* :mod:`storage.missiondb` — mission.db, the coordinator's append-only mission log
  (``MissionStore``; ``load_events``, ``load_meta``, ``highest_epoch`` read it);
* :mod:`storage.carrierlog` — a carrier's durable log (``CarrierLog``; ``read_log``, ``log_path``);
* :mod:`storage.sqlite` — what both share: opening a file in WAL mode, read-only access, the
  ``meta`` table.

It sits below the processes and ``recording/`` (which read the stores through it) and imports
only the standard library and ``mission.events``.
"""
