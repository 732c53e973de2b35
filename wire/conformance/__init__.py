"""The conformance kits: check a third-party carrier, or a third-party coordinator, against
docs/protocol.md, rule by rule.

    python -m wire.conformance [carrier] SCENARIO --carrier ID [options] -- COMMAND [ARGS...]
    python -m wire.conformance coordinator [SCENARIO] [options] -- COMMAND [ARGS...]

The coordinator kit (``coordkit``) is the router and every carrier of the scenario (``fleet``:
the scenario's truth and the kit's carriers; ``coordflight``: its flights, faults and what it
saw; ``coordrules``: :data:`COORDINATOR_RULES` and their evaluation). The rest of this
docstring is the carrier kit, the default:

The kit is the mission's zenoh router (mode ``router``, ``tcp/127.0.0.1:<free port>``,
multicast scouting off) and a passive observer of every message of the mission. In its default
flight (``--flight project``; the others play the coordinator themselves, ``scripted``) it starts the
project's coordinator (``run_fleet.py --role coordinator``, a client of the router) and the
scenario's other carriers (``run_fleet.py --role carrier --no-autonomy``, one process), then
COMMAND, the carrier under test, told where and who it is by environment variables and by
placeholders in ARGS (docs/protocol.md, section 11):

    MARSUPIAL_ENDPOINT  {endpoint}   the endpoint to connect to (zenoh client mode)
    MARSUPIAL_CARRIER   {carrier}    the carrier id it flies as
    MARSUPIAL_SCENARIO  {scenario}   the scenario file (absolute path)
    MARSUPIAL_MISSION   {mission}    the mission id (key prefix marsupial/<mission>/)
    MARSUPIAL_SEED      {seed}       the root seed (the fingerprint's)
    MARSUPIAL_WORKDIR   {workdir}    a directory of its own for files it writes (logs)

During the mission it makes deliberate faults (``--faults``, all by default): ``late`` (the
coordinator is frozen, SIGSTOP, for ``--late`` seconds once the carrier has sent its Observation of
stage 1: that Decision comes late), ``duplicate`` (the Decision of stage 0 is published again once
the carrier has answered it), ``restart`` (the coordinator is killed, SIGKILL, once the carrier
has answered stage 1, and restarted on its mission.db: epoch 2), ``deposed`` (after the restart,
a Decision of epoch 1 for the stage the carrier waits at, selecting it, while the coordinator is
frozen; published only when no real Decision of that stage arrives within ``SETTLE_S`` of the
freeze, else tried at a later stage, so the fake one always comes first). Then it prints one
line per rule: how many times the carrier was exercised on it, pass or fail, and the first
message that broke it. Exit status 0 only when every exercised rule passes (1 otherwise, 2 for a
usage error).

The rules are :data:`RULES`; each cites the rule of docs/protocol.md it comes from.

The parts, each doing one thing (each given its collaborators in its constructor):

* ``flight``: the carrier under test and the scenario's truth about it (``Target``), what the
  kit saw (``Seen``, ``Flight``), and the ``Observer`` filing the router's traffic into a flight;
* ``harness``: the kit's router and the processes (coordinator, other carriers, the carrier under
  test and its placeholders);
* ``faults``: the project flight's deliberate faults and their triggers;
* ``scripted``: the coordinators the kit plays itself in the other flights (``--flight``: scripted,
  progress, refusal, older, gap, two-coordinators, two-ballots, unanswered);
* ``rules``: the rules and their evaluation, a pure function of the target and the flight;
* ``report``: the table and the verdict; ``kit``: ``Kit``, the flight loop tying them together;
* ``cli``: the command line, ``main(argv)`` (both kits).
"""
from __future__ import annotations

from . import coordflight, coordrules, fleet
from .cli import main
from .coordkit import CoordinatorKit
from .coordrules import COORDINATOR_RULES
from .faults import FAULTS, SETTLE_S
from .flight import CARRIER_TOPICS, Flight, Seen, Target
from .kit import FLIGHTS, Kit
from .report import passed, table, verdict
from .rules import RULES, Result, evaluate

__all__ = [
    "CARRIER_TOPICS", "COORDINATOR_RULES", "CoordinatorKit", "FAULTS", "FLIGHTS", "RULES",
    "SETTLE_S", "Flight", "Kit", "Result", "Seen", "Target", "evaluate", "coordflight",
    "coordrules", "fleet", "main", "passed", "table", "verdict"
]
