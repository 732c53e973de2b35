"""A carrier's join paths, one implementation for the carrier process (carriers/joining.py) and
the deterministic simulator (mission/simulate/carrier.py): from the coordinator's State and the
carrier's own durable log, or from its log alone when no coordinator answers.

A path is a generator of what it asks of its driver, which owns the body, the clock and the
wire: :class:`Drive` (the body to stage j's time, unpaced; answered with the position there),
:class:`Here` (the position now), :class:`Apply` (an event of its :mod:`mission.carrier` machine;
answered with the machine after it), :class:`Execute` (an effect of that machine) and
:class:`Release` (a passenger out in the carrier's world). It feeds the carrier's
:class:`mission.peers.PeerBook` itself. Drivers carry the requests out with
:func:`mission.timers.drive`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Generator, Iterable

from . import carrier as mc
from .peers import PeerBook


@dataclass(frozen=True)
class Drive:
    """The carrier's body driven to stage ``stage``'s time, unpaced; answer: its position there."""

    stage: int


@dataclass(frozen=True)
class Here:
    """Answer: the carrier's position now."""


@dataclass(frozen=True)
class Apply:
    """Step the carrier's machine with ``event`` (and carry out its effects); answer: the machine."""

    event: Any


@dataclass(frozen=True)
class Execute:
    """Carry out this effect of the carrier's machine."""

    effect: Any


@dataclass(frozen=True)
class Release:
    """A passenger released in the carrier's world at stage ``stage`` (a deployment replayed)."""

    stage: int


#: A join path: what it asks, what its driver answers, what it returns.
Steps = Generator[Any, Any, Any]


def from_state(machine: mc.Handshake, seen: mc.StateSeen, entries: Iterable, book: PeerBook) -> Steps:
    """Join from the coordinator's State (``seen``) and the carrier's own durable log (``entries``,
    each with ``stage``, ``status``, ``deployed``, ``x``): the deployments on record replayed,
    the stages it resolved itself that the coordinator has not decided recalled (it decided them
    on board while the coordinator was away), its Hello, then the deployments on record it never
    made answered ``late`` and its own decisions of the recalled stages said again. A State that
    says the mission ended replays and recalls nothing."""
    done = {e.stage: e for e in entries if e.status is not None}
    logged = {j: e.deployed for j, e in done.items()} or None  # no outcome logged: the record decides
    start = mc.join_stage(seen.next_stage, logged)
    recalled = [j for j in sorted(done) if j >= seen.next_stage]
    if not seen.ended:
        machine = yield from _replay(machine, mc.replay_plan(machine, min(seen.next_stage, start), seen.deployments,
                                                              logged), book)
        for j in recalled:  # kept as they were (mission.carrier.Recalled: its Own sent again)
            e = done[j]
            position = yield Drive(j)
            machine = yield Apply(mc.Recalled(j, e.status, e.deployed, position, e.x))
            if e.deployed:
                yield Release(j)
            book.outcome(machine.cid, j, e.deployed)
    machine = yield Apply(mc.Joined(start, seen.ended, seen.epoch, seen.coordinator))
    yield Execute(mc.SendHello(machine.hello_stage(), machine.passengers_left))
    # after its Hello (it is accepted first)
    for j in mc.missed(seen.next_stage, seen.deployments, logged):
        position = yield Here()
        machine = yield Apply(mc.Missed(j, position))
    for effect in mc.accounts(machine, recalled):
        yield Execute(effect)


def alone(machine: mc.Handshake, entries: Iterable, book: PeerBook,
          counts: Callable[[int, Any], Any] = lambda j, x: None) -> Steps:
    """Join with no coordinator (decentralised, or none answered: hybrid): go on from the
    carrier's own log (``entries``: what it observed and resolved, into its book with the region
    ``counts(j, x)`` behind an observation; the deployments on record replayed in its world).
    Returns the stage it joins at once its peers are there: the one after the last its log
    resolved."""
    done = [e for e in entries if e.status is not None]
    for e in done:
        if e.observed:
            book.observation(machine.cid, e.stage, e.x, counts(e.stage, e.x))
        book.outcome(machine.cid, e.stage, e.deployed)
    next_stage = max((e.stage + 1 for e in done), default=0)
    yield from _replay(machine, mc.replay_plan(machine, next_stage, [e.stage for e in done if e.deployed]), book)
    return next_stage


def _replay(machine: mc.Handshake, stages: Iterable[int], book: PeerBook) -> Steps:
    """The deployments on record at ``stages`` (ascending, at most the passengers on board:
    :func:`mission.carrier.replay_plan`) replayed: the body driven to each stage, a passenger
    released there. Returns the machine after them."""
    for j in stages:
        position = yield Drive(j)
        machine = yield Apply(mc.Replayed(j, position))
        yield Release(j)
        book.outcome(machine.cid, j, True)
    return machine
