"""The planner's command lines: the one place in planner/ with argparse and exit codes.

* ``python -m planner.cli.solve``    one planner online over an instance file, as one JSON object;
* ``python -m planner.cli.bench``    the MCTS benchmark;
* :mod:`planner.cli.measure`         ``python -m planner.online_optimal`` and ``python -m
  planner.clairvoyant`` (their modules' ``__main__`` blocks forward here).

Each module imports the planner core and the standard library only (numpy included, as the core
does); nothing of planner/ imports these modules. The earlier spellings ``python -m
coordinator.solve`` and ``python -m coordinator.bench`` forward here.
"""
