"""Every timeout of the fleet, in one place: the coordinator's and carriers' configs and
run_fleet.py's flags take their defaults from :data:`DEFAULTS`.

All values are seconds of wall time. Which of them end a wait depends on the mission's clock
(:data:`CLOCKS`, docs/fleet.md, "Simulated time and wall time"): on the ``sim`` clock (every
simulated mission, whatever its ``--realtime`` pace) only failure detection ends a wait for a
participant that is live and making progress (its liveliness token, the Zenoh lease,
``silence_s``); on the ``wall`` clock (real robots) ``stage_s``, ``decision_s`` and ``peer_s``
are deadlines, and a late observation is legitimately ∅. On links slower than a LAN (acoustic),
:func:`over_links` lengthens the waits that cross them by the link model's latency bound.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

#: Default simulated seconds between two Pose messages of a carrier (0: none), and between two
#: poses of a recording rebuilt from mission.db.
POSE_INTERVAL_S = 1.0
#: Unpaced, a carrier sends a stage's Poses in one burst when it drives to the stage; without
#: ``--pose-interval`` it sends at most this many a stage (:func:`pose_interval`).
POSES_PER_STAGE = 20


def pose_interval(stage_interval_s: float, realtime: float) -> float:
    """run_fleet.py's ``--pose-interval`` when it is not given: :data:`POSE_INTERVAL_S`, or in an
    unpaced mission (``realtime`` 0) the whole seconds that keep a carrier within
    :data:`POSES_PER_STAGE` Poses a stage. A burst of Δt / 1 s Poses per carrier and stage is
    nothing a viewer can follow at ``--realtime 0``, and with long stages it costs more than the
    mission's physics (docs/performance.md, "Where a stage's wall time goes")."""
    if realtime > 0 or stage_interval_s <= POSES_PER_STAGE * POSE_INTERVAL_S:
        return POSE_INTERVAL_S
    return float(math.ceil(stage_interval_s / POSES_PER_STAGE))

#: A State query that got no reply is asked again this long after (s; docs/protocol.md, [P-5.2]);
#: opening a Zenoh session is retried as often.
STATE_RETRY_S = 0.2

#: The mission clocks: ``sim`` (a simulated mission: slow work is waited for) and ``wall`` (a
#: real-time mission: wall-clock deadlines).
CLOCKS = ("sim", "wall")


@dataclass(frozen=True)
class Timeouts:
    """Wall-clock waits of the stage handshake (docs/fleet.md, "Flags").

    Attributes:
        join_s: coordinator: before stage 0, wait this long for every carrier's token and Hello.
        stage_s: coordinator, wall clock: per stage, wait this long for the expected observations.
        confirm_s: coordinator: after the last decision, wait this long for its Confirms.
        bye_s: coordinator: after End, repeat it and wait this long for the carriers' Byes.
        bye_grace_s: coordinator: after End, a carrier whose token vanished without a Bye gets
            this long more (within ``bye_s``): its Bye and its token's end travel on different
            subscriptions, in either order.
        end_repeat_s: coordinator: interval between two publications of End.
        decision_s: carrier: wall clock: longest wait for one stage's decision while the coordinator
            is present (then it decides the stage itself); sim clock: after this long it asks the
            coordinator's State again (a lost decision is recovered) and goes on waiting.
        coordinator_s: carrier: exit when the coordinator has been absent this long (also the
            time it keeps trying to open its session and to get an answer from State).
        end_s: carrier: after its last stage, wait this long for End before saying Bye
            (``finished``).
        state_query_s: either side: one State query waits this long for replies.
        close_s: either side: bound on undeclaring everything and closing the Zenoh session.
        liveliness_check_s: either side, at start: how long the liveliness query that looks for
            a live process with the same role and id (a duplicate) waits for answers.
        standby_poll_s: a standby coordinator: how often it looks whether the primary's
            liveliness token is still there (the takeover delay is at most this, after zenoh
            noticed the primary's loss).
        standby_state_s: a standby coordinator: how often it queries the primary's State to
            learn its epoch.
        peer_s: a carrier deciding alone, wall clock: per stage, wait this long for the
            observations of the carriers it hears.
        progress_s: sim clock: a carrier working towards its next observation (simulating a long
            stage) sends a Progress message at least this often.
        silence_s: sim clock: a live participant from whom nothing (not even Progress) has arrived
            for this long while it is waited for is taken as stalled: the coordinator goes on
            without its observation, a carrier deciding alone without its peer's. Only a
            process that is alive but stuck gets there: a slow one sends Progress, a dead one
            loses its token, a cut-off one its lease.
        hello_s: carrier: its latest Hello unanswered this long while the coordinator's token is
            present, it says Hello again, then after twice as long, doubling (docs/protocol.md,
            [P-5.14]). As long as Zenoh's lease (10 s): a coordinator stopped for longer loses its
            token, so a Hello unanswered by then was lost on the way, not just slow.
        rejoin_s: coordinator resumed on a mission on record: its join wait
            (:meth:`resumed_join_s`; None: the smaller of ``join_s`` and ``stage_s``).
    """

    join_s: float = 20.0
    stage_s: float = 5.0
    confirm_s: float = 3.0
    bye_s: float = 2.0
    bye_grace_s: float = 0.5
    end_repeat_s: float = 0.5
    decision_s: float = 30.0
    coordinator_s: float = 30.0
    end_s: float = 10.0
    state_query_s: float = 2.0
    close_s: float = 3.0
    liveliness_check_s: float = 1.5
    standby_poll_s: float = 0.25
    standby_state_s: float = 2.0
    peer_s: float = 5.0
    progress_s: float = 1.0
    silence_s: float = 30.0
    hello_s: float = 10.0
    rejoin_s: float | None = None

    def resumed_join_s(self) -> float:
        return resumed_join(self.join_s, self.stage_s, self.rejoin_s)


def resumed_join(join_s: float, stage_s: float, rejoin_s: float | None = None) -> float:
    """A resumed coordinator's join wait ([P-5.11]): ``rejoin_s`` when set (:func:`over_links`),
    else the smaller of the join and the stage timeout (some carriers may be gone: the mission is
    not held a whole join timeout for them)."""
    return min(join_s, stage_s) if rejoin_s is None else rejoin_s


#: The defaults.
DEFAULTS = Timeouts()

#: Largest accepted difference between a message's ``t`` (an Observation's, a Decision's) and
#: the stage time t_j it names, seconds.
T_TOLERANCE_S = 1e-3

#: The waits that cross the links, and how many one-way messages each covers: what it waits for
#: and what must go out first (docs/fleet.md, "Waits over slow links"). The others are local
#: (a session's close, a liveliness query) or the pace of periodic messages (Progress).
LINK_WAITS = {
    "join_s": 3,          # a carrier's State query, the State reply, its Hello
    "stage_s": 2,         # the Decision of the stage before out, the Observation back
    "confirm_s": 2,       # the last Decision out, its Confirm back
    "bye_s": 2,           # End out, the Bye back
    "bye_grace_s": 1,     # a Bye crossing the links while its token's end does not
    "end_repeat_s": 1,    # End said again no sooner than one crosses the channel
    "decision_s": 2,      # the Observation out, the Decision back
    "coordinator_s": 2,   # the State query out, its reply back
    "end_s": 2,           # the last Confirm out, End back
    "peer_s": 1,          # the peers' Observations
    "silence_s": 1,       # a Progress late by a crossing
    "hello_s": 2,         # the Hello out, its Accepted back
}
#: A resumed coordinator's join wait covers a Resync: State query, reply and Hello.
REJOIN_MESSAGES = 3


def over_links(base: Timeouts, latency_s: float, given=()) -> Timeouts:
    """The waits of a mission whose links take up to ``latency_s`` seconds one way (the link
    model's bound, :func:`world.fleet_links.latency_bound`): each wait of :data:`LINK_WAITS` is
    its value in ``base`` plus as many ``latency_s`` as the messages it covers, except those named
    in ``given`` (set explicitly, by a flag: they stand as given). A resumed coordinator's join
    wait becomes the smaller of ``base``'s join and stage timeouts plus :data:`REJOIN_MESSAGES`
    latencies, at most the join wait. ``latency_s`` 0 (perfect and radio links): ``base``."""
    if latency_s <= 0:
        return base
    if latency_s != latency_s or latency_s == math.inf:
        raise ValueError(f"latency_s: expected a finite number of seconds, found {latency_s}")
    longer = {name: getattr(base, name) + n * latency_s for name, n in LINK_WAITS.items() if name not in given}
    out = dataclasses.replace(base, **longer)
    rejoin = min(base.join_s, base.stage_s) + REJOIN_MESSAGES * latency_s
    return dataclasses.replace(out, rejoin_s=min(out.join_s, rejoin))
