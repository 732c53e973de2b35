"""The pure planner core: where and when carriers deploy their passengers.

Imports numpy, scipy and numba only (never zenoh, pymunk, msgpack, sqlite3, matplotlib or any
process package). This package module itself stays light — importing ``planner`` or
``planner.limits`` loads nothing heavy — so that carriers can use the limits cheaply; the
modules with numba kernels are imported on first use by :mod:`planner.registry`.

Modules, bottom up:

* :mod:`planner.limits`    size limits shared by scenario validation and the wire;
* :mod:`planner.settings`  planner defaults and choice lists (below every planner and the registry);
* :mod:`planner.priors`    prior kinds (spec checking, scipy distributions, support points);
* :mod:`planner.problem`   the problem model, the penalty rule, stage views;
* :mod:`planner.ssap`      DLR thresholds and the threshold rule;
* :mod:`planner.compiled`  the compiled problem every planner reads (sampler, thresholds, CSR
  conflicts, valid stages left);
* :mod:`planner.policies`  the ``random`` and ``ssap`` planners;
* :mod:`planner.mcts`      MCTS-SSAP / MCTS-Random (fast numba kernels and the plain reference);
* :mod:`planner.closedloop`  the ``closed-loop`` planner;
* :mod:`planner.clairvoyant`  the offline optimum (upper bound);
* :mod:`planner.registry`  planner names, options and their validation;
* :mod:`planner.online`    the online loop: ``stage_step`` and ``run_online``;
* :mod:`planner.instance`  the JSON instance format;
* :mod:`planner.solve`    the solve command's work (the command line is :mod:`planner.cli.solve`);
* :mod:`planner.conformance`  the conformance kit of a planner plug-in (its command line is
  :mod:`planner.cli.conformance`).

The core has no command line: the planner's command lines (solve, bench, the exact solvers'
measurements, conformance) are in :mod:`planner.cli`, the one place in planner/ with argparse;
``python -m planner.online_optimal``, ``planner.clairvoyant`` and ``planner.conformance`` run
``__main__`` blocks that only forward there. planner/ imports nothing above it.
"""
