"""What a simulated mission must never do (:class:`Invariants`), checked after every event of
:class:`mission.simulate.simulation.Simulation` and at its end (docs/fleet.md, "Deterministic
simulation": the invariants)."""
from __future__ import annotations

import numpy as np

from .. import carrier as mc
from .. import events as ev
from .. import state as ms
from ..ballot import Ballot
from .model import FAITHFUL_KINDS, Outcome


class Invariants:
    """The mission's physical truth and its findings: what left each carrier (``releases``:
    carrier id -> stages), the Confirms each store recorded, the ballots that decided each stage,
    and the violations found (each one line, at most :data:`MAX_VIOLATIONS`).

    Args:
        sim: the :class:`mission.simulate.simulation.Simulation` it watches (its time, fleet,
            carriers and coordinators are read, never changed).
    """

    MAX_VIOLATIONS = 20

    def __init__(self, sim):
        self.sim = sim
        self.violations: list = []
        self.releases: dict = {cid: [] for cid in sim.fleet.ids}
        self.confirmed: set = set()     # (disk, carrier, stage): each store records a Confirm once
        self.decided: dict = {}         # (ballot, stage) -> the coordinator that published it

    def violate(self, line: str) -> None:
        if len(self.violations) < self.MAX_VIOLATIONS:
            self.violations.append(f"t={self.sim.t:.3f} s: {line}")

    def released(self, driver, j: int) -> None:
        """A passenger left carrier ``driver`` at stage j: the physical truth."""
        cid, passengers = driver.cid, self.sim.fleet.passengers[driver.r]
        if j in self.releases[cid]:
            self.violate(f"carrier {cid} deployed a second passenger at stage {j}")
        self.releases[cid].append(j)
        if len(self.releases[cid]) > passengers:
            self.violate(f"carrier {cid} deployed {len(self.releases[cid])} passengers, it has {passengers}")

    def check_carrier(self, driver, before, event, effects) -> None:
        for effect in effects:
            if isinstance(effect, mc.Deploy) and effect.stage != before.stage:
                self.violate(f"carrier {driver.cid} deployed at stage {effect.stage} while at stage {before.stage}")
            if isinstance(effect, mc.LogOutcome) and isinstance(event, mc.DecisionHeard):
                said = Ballot(event.epoch, event.coordinator)
                if said.below(before.ballot):
                    self.violate(f"carrier {driver.cid} acted on a Decision of ballot {said} for stage "
                                 f"{event.stage} after hearing ballot {before.ballot}")
                true = Ballot(event.epoch, driver.sender)  # who sent it, whatever the message says
                if true.below(driver.acted):
                    self.violate(f"carrier {driver.cid} acted on a Decision of ballot {true} for stage {event.stage} "
                                 f"after acting on one of ballot {driver.acted}")
                driver.acted = driver.acted.highest(true)

    def check_on_board(self, driver) -> None:
        """A flying carrier counts the passengers it carries (its restarts included)."""
        m, carried = driver.machine, self.sim.fleet.passengers[driver.r] - len(self.releases[driver.cid])
        if m.flying and m.passengers_left != carried:
            self.violate(f"carrier {driver.cid} counts {m.passengers_left} passenger(s) on board, it carries {carried}")

    def check_coordinator(self, driver, before, event, effects) -> None:
        for effect in effects:
            if not isinstance(effect, ms.Record):
                continue
            e = effect.event
            if isinstance(e, (ev.Bye, ev.Observation, ev.Confirmed)) and e.carrier not in before.accepted:
                self.violate(f"{driver.name} recorded a {type(e).__name__} of {e.carrier} without its accepted Hello")
            if isinstance(e, ev.Confirmed):
                key = (driver.disk.name, e.carrier, e.stage)  # each store records it once
                if key in self.confirmed:
                    self.violate(f"{driver.name} recorded a second Confirm of {e.carrier} at stage {e.stage}")
                self.confirmed.add(key)
            if isinstance(e, ev.Decided):
                first = self.decided.setdefault((driver.ballot, e.stage), driver.name)
                if first != driver.name:
                    self.violate(f"two coordinators decided stage {e.stage} in ballot {driver.ballot}")

    def check_authority(self, driver, before: tuple, m) -> None:
        """No carrier's message changes who decides (docs/protocol.md [P-7.3]): a coordinator's
        ballot, and its deciding, are the same after it handled a carrier's message."""
        after = driver.authority()
        if after != before:
            self.violate(f"carrier {m.src}'s {m.kind} changed who decides: {driver.name} ballot "
                         f"{before[0]} -> {after[0]}, deposed unfenced {before[1]} -> {after[1]}")

    def check_record(self, record_events) -> None:
        """No deployment lost or counted twice: the mission's record — ``record_events`` (its
        mission.db) merged with the carriers' logs, as the report merges them
        (:func:`mission.report.merge`) — holds exactly the passengers that left each carrier."""
        from ..report import CarrierRecord, merge

        sim, physical = self.sim, {cid: sorted(js) for cid, js in self.releases.items()}
        logs = [CarrierRecord(cid, f"carriers/{cid}.db", {}, tuple(sorted(d.log.values(), key=lambda e: e.stage)))
                for cid, d in sim.carriers.items()]
        merged = merge(sim.spec, record_events, logs)
        confirmed = merged.state.confirmed_deployments()
        lying = {f.who for f in sim.faults if f.kind == "compromised"}  # its record holds what it claimed
        for r, cid in enumerate(sim.fleet.ids):
            if cid in lying:
                continue
            record, made = merged.state.deployments_of(cid), set(physical[cid])
            sure = set(np.flatnonzero(confirmed[r]).tolist())
            if sim.carriers[cid].phase == "done" and cid in merged.state.byes and record != physical[cid]:
                # its Bye on record: it told the coordinator all it made (one whose Bye was lost, e.g.
                # a coordinated carrier giving up while the coordinator was down, is as one that
                # never came back: a Decision for it after it left counts as gone)
                self.violate(f"the mission's record (mission.db and the carriers' logs) has deployments {record} "
                             f"of {cid}, which deployed at {physical[cid]}")
            elif not sure <= made <= set(record):
                # a carrier that never came back: its unanswered decisions may or may not have been made
                self.violate(f"the mission's record has deployments {record} (confirmed {sorted(sure)}) of {cid}, "
                             f"which never came back and deployed at {physical[cid]}")

    def conclude(self, bound: float) -> Outcome:
        """The mission's outcome once its loop stopped: what left each carrier, the reward, and
        the checks at the end (completed within ``bound``; the record; a faithful schedule decides
        as the offline planner)."""
        from planner.problem import evaluate

        sim = self.sim
        fleet = sim.fleet
        out = Outcome(sim.seed, sim.faults, sim.trace.hexdigest(), sim.events, seconds=sim.t)
        out.deployments = {cid: sorted(js) for cid, js in self.releases.items()}
        deployed = np.zeros(fleet.valid.shape, dtype=bool)
        for cid, js in self.releases.items():
            deployed[fleet.ids.index(cid), js] = True
        out.reward = float(evaluate(fleet.problem, deployed, fleet.x)[0])
        out.completed = sim.done()
        if sim.links is not None:
            out.links = {"sent": sim.links.sent, "lost": sim.links.lost}
        final = next((d for d in sim.coordinators.values() if d.phase == "done"), None)
        if not out.completed:
            self.violate(f"the mission did not complete within its liveness bound of {bound:.0f} s "
                         + ", ".join(f"{n}:{d.phase}" for n, d in sim.coordinators.items()) + " "
                         + ", ".join(f"{c}:{d.phase}" for c, d in sim.carriers.items() if d.phase != "done"))
        else:
            self.check_record(sim.db)
        if out.completed and self.faithful():
            offline = fleet.offline()
            if final is not None and {j: d.deploy for j, d in final.state.decisions.items()} != offline:
                self.violate("the fleet's decisions differ from the offline planner's (faults: "
                             + ", ".join(f.kind for f in sim.faults) + ")")
        out.violations = self.violations
        return out

    def faithful(self) -> bool:
        """Nothing lost for long: faithful fault kinds only, and no message lost by the link model
        (its delays alone are faithful)."""
        sim = self.sim
        return all(f.kind in FAITHFUL_KINDS for f in sim.faults) and (sim.links is None or sim.links.lost == 0)
