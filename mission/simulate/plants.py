"""Known bug classes put back, one at a time, for the campaign's power test (docs/fleet.md,
"Deterministic simulation": power): the machines' step functions as a planted bug changes them,
and what a carrier reads of a message under one. ``plant`` None: the real rules."""
from __future__ import annotations

import dataclasses

from .. import carrier as mc
from .. import events as ev
from .. import state as ms
from ..ballot import Ballot

#: The bug classes: an identical repeated Confirm counted twice, a deployment forgotten on
#: restart, a Decision of an older epoch accepted, a slow carrier taken as ∅ (its Progress not
#: heard), a Bye without Hello accepted, carriers that rank coordinators by their epoch alone (no
#: ballots: the coordinator id not read).
PLANTS = ("confirm-twice", "forget-on-restart", "older-epoch", "slow-as-empty", "bye-without-hello", "no-ballot")


def planted_coordinator_step(plant: str | None, state, event):
    """:func:`mission.state.step`, or as ``confirm-twice`` or ``bye-without-hello`` breaks it."""
    new, effects = ms.step(state, event)
    if plant == "confirm-twice" and isinstance(event, ev.Confirmed) and not effects:
        first = state.confirms.get((event.carrier, event.stage))
        if first is not None and first.deployed == event.deployed:
            effects = (ms.Record(event, event.stage),)  # the planted bug: a repeat counted again
    if plant == "bye-without-hello" and isinstance(event, ev.Bye) and effects and isinstance(effects[0], ms.Reject) \
            and effects[0].reason in ("no-hello",):
        new = dataclasses.replace(state, byes=state.byes | {event.carrier})
        effects = (ms.Record(event, None),)
    return new, effects


def planted_carrier_step(plant: str | None, state, event):
    """:func:`mission.carrier.step`, or as ``older-epoch`` breaks it (no ballot check)."""
    if plant == "older-epoch" and isinstance(event, mc.DecisionHeard) \
            and Ballot(event.epoch, event.coordinator).below(state.ballot):
        event = dataclasses.replace(event, epoch=state.epoch, coordinator=state.coordinator)
    return mc.step(state, event)


def read_coordinator(plant: str | None, m) -> str:
    """The coordinator id a carrier reads in message ``m`` (its ballot's); "" under ``no-ballot``,
    as before revision 6."""
    return "" if plant == "no-ballot" else m.get("coordinator", "")
