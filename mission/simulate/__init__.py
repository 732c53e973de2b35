"""Deterministic simulation of a whole fleet: the real state machines on a simulated network and
clock, faults drawn from a seed, invariants after every event (docs/fleet.md, "Deterministic
simulation"; docs/architecture.md, "Time as an input").

One process runs a mission's coordinator(s) and carriers as drivers of the real pure machines —
:func:`mission.state.step` (the coordinator's rules, and :func:`mission.state.fold` over its
durable record for a restart), :func:`mission.carrier.step` (a carrier's), the timer rules of
:mod:`mission.timers` and the real planners (the stage step of ``planner.online``; on board,
``decide_local`` on a :class:`mission.peers.PeerBook` view) — on a discrete-event loop:

* **network**: every message goes through the router; per link and message a delay from a
  lognormal (per-link median from the seed), and in fault windows loss, duplication, reordering
  (a widened delay), a partition of one host (its messages and tokens lost both ways, the tokens
  vanishing a lease after the cut and reappearing at the heal) or the router lost (every host
  cut);
* **clocks**: one per host, with an offset, a drift and (a fault) forward jumps; the timer rules
  read the host's clock, never the simulated true time;
* **faults** (:data:`FAULT_KINDS`), drawn from the mission's seed: a schedule of timed actions.

Everything random comes from one ``numpy.random.Generator`` per mission, seeded by the mission's
seed; the loop breaks ties by insertion order. The same seed gives the same event trace: its
hash (:attr:`Outcome.trace_hash`) is the check.

This package is pure like the rest of mission/: it imports the planner core and numpy, nothing of
zenoh, pymunk, msgpack or sqlite. The scenario comes in as a :class:`Fleet` (built from a
scenario file by :mod:`launcher.simulate`, which ``python -m mission.simulate`` runs).

The package: :mod:`.model` (constants, messages, clocks, faults, the outcome), :mod:`.fleet`
(the scenario's numbers and the planners' memo), :mod:`.coordinator` and :mod:`.carrier` (the
processes' drivers), :mod:`.simulation` (the loop, the network, the faults, the invariants).
"""
from __future__ import annotations

from .carrier import CarrierDriver
from .coordinator import CoordinatorDriver, Disk
from .fleet import Fleet
from .model import (FAITHFUL_KINDS, FAULT_KINDS, LEASE_S, ROUTER, Clock, Fault, LogEntry, Msg, Outcome, draw_faults,
                    msg)
from .plants import PLANTS
from .simulation import OVERRUN_S, Simulation, combined_hash, simulate

__all__ = ["FAITHFUL_KINDS", "FAULT_KINDS", "LEASE_S", "OVERRUN_S", "PLANTS", "ROUTER", "CarrierDriver", "Clock",
           "CoordinatorDriver", "Disk", "Fault", "Fleet", "LogEntry", "Msg", "Outcome", "Simulation", "combined_hash",
           "draw_faults", "msg", "simulate"]
