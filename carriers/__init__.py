"""The carrier process: drives its own body in its own copy of the world, senses, publishes,
waits for the stage's decision, deploys and confirms. See carriers/node.py and docs/fleet.md."""

#: When the on-board planner is loaded (:class:`carriers.onboard.Onboard`); None in a config:
#: ``start`` for a process that simulates one carrier, ``need`` for several. Defined here, where
#: reading it loads nothing else (run_fleet.py's flags).
ONBOARD_LOADS = ("start", "need")
