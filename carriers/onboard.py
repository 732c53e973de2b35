"""The on-board planner of a process's carriers: what a carrier runs when it decides a stage
itself (docs/fleet.md, "Without the coordinator"), loaded once per process and only when the
load policy says so."""
from __future__ import annotations

import threading
from dataclasses import replace

import world
from mission.peers import conflict_adjacency, listened
from planner.settings import ONBOARD_PLANNER



class Onboard:
    """The on-board planner (:data:`planner.settings.ONBOARD_PLANNER`) and the planner's instance of the scenario,
    shared by the process's carriers (fully informed carriers compute the same joint action: it is
    computed once). Loading the planner core (numba, scipy, the compiled kernels) and the stage
    geometry takes seconds of CPU and a planner's memory (docs/performance.md, "Costs behind the
    fleet's constants"), so when it is loaded is a setting (:data:`carriers.ONBOARD_LOADS`,
    ``CarrierConfig.onboard_load``):

    * ``start``: in the background when the carrier starts (:meth:`prepare`), not when the
      coordinator is already gone; the default of a process that simulates one carrier (a robot);
    * ``need``: in the background when the coordinator's token vanishes, and at the latest when
      the carrier decides alone (a decision later than its timeout); until then the carrier
      neither loads the planner nor listens to its peers. The default of a process that simulates
      several carriers (large simulations: every process loading it at once, and subscribing to
      its peers, delays a large fleet's join). A decision that is merely late does not load it:
      in an overloaded simulation that would add the load's memory and CPU to every process just
      when the CPU is short.

    A carrier that never decides alone (``coordinated``) never loads it; a decentralised one
    always does at the start."""

    def __init__(self, scenario, options=()):
        self.scenario = scenario
        self.options = dict(options)
        self._lock = threading.Lock()
        self._built = None
        self._preparing = None
        self._adjacency = None

    def prepare(self) -> None:
        """Build in a background thread (once)."""
        with self._lock:
            if self._built is not None or self._preparing is not None:
                return
            self._preparing = threading.Thread(target=self.get, name="onboard-planner", daemon=True)
        self._preparing.start()

    def ready(self) -> bool:
        return self._built is not None

    def get(self):
        """(problem, planner), built on first use."""
        with self._lock:
            if self._built is None:
                from planner.registry import make_planner, used_options

                problem = world.build_problem(self.scenario)
                planner = make_planner(ONBOARD_PLANNER, **used_options(ONBOARD_PLANNER, self.options))
                planner.warm_up(problem)
                self._built = (problem, planner)
            return self._built

    def listened(self, r: int) -> list[int]:
        """The carriers carrier ``r`` listens to (:func:`mission.peers.listened`), over the
        conflict graph of the instance, built once for the process's carriers."""
        problem, _ = self.get()
        with self._lock:
            if self._adjacency is None:
                self._adjacency = conflict_adjacency(problem)
        return listened(problem, r, adjacency=self._adjacency)


def with_onboard_load(configs) -> list:
    """The configs with ``onboard_load`` filled in where left open: ``start`` for a process that
    simulates one carrier, ``need`` for several (:class:`Onboard`)."""
    configs = list(configs)
    load = "start" if len(configs) == 1 else "need"
    return [c if c.onboard_load is not None else replace(c, onboard_load=load) for c in configs]
