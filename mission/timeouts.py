"""Every timeout of the fleet, in one place: the coordinator's and carriers' configs and
run_fleet.py's flags take their defaults from :data:`DEFAULTS`.

All values are seconds of wall time.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Timeouts:
    """Wall-clock waits of the stage handshake (docs/fleet.md, "Flags").

    Attributes:
        join_s: coordinator: before stage 0, wait this long for every carrier's token and Hello.
        stage_s: coordinator: per stage, wait this long for the expected observations.
        confirm_s: coordinator: after the last decision, wait this long for its Confirms.
        bye_s: coordinator: after End, repeat it and wait this long for the carriers' Byes.
        end_repeat_s: coordinator: interval between two publications of End.
        decision_s: carrier: longest wait for one stage's decision while the coordinator is present.
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
    """

    join_s: float = 20.0
    stage_s: float = 5.0
    confirm_s: float = 3.0
    bye_s: float = 2.0
    end_repeat_s: float = 0.5
    decision_s: float = 30.0
    coordinator_s: float = 30.0
    end_s: float = 10.0
    state_query_s: float = 2.0
    close_s: float = 3.0
    liveliness_check_s: float = 1.5
    standby_poll_s: float = 0.25
    standby_state_s: float = 2.0


#: The defaults.
DEFAULTS = Timeouts()
