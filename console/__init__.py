"""The operator console: a person at the base station sees each stage's recommendation and its
reasons, and approves, vetoes or forces deployments (docs/fleet.md, "The operator console").

A process-side part of the coordinator: :mod:`console.desk` takes actions from the page and
from the mission's operator key, :mod:`console.hold` is the stage's wait for the operator and
the planner's re-decision under the constraints, :mod:`console.view` what the page shows,
:mod:`console.server` the page itself (the standard library's http.server). The planner sees
only constraints (:mod:`planner.constraints`).

The defaults below are what run_fleet.py's flags read; this module loads nothing else.
"""

#: The console's TCP port on 127.0.0.1 (``--operator-port``).
PORT = 8780
#: Seconds the recommendation waits for the operator before it stands (``--operator-timeout``).
TIMEOUT_S = 5.0
#: The identity of actions taken on the page (the Zenoh key's carry their sender's).
CONSOLE_OPERATOR = "console"
