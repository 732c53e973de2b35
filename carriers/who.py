"""Which carrier of which mission (:class:`Who`), and the wire messages it sends, built from the
effects of its machine and what it knows (each as (key, message): the carrier puts them)."""
from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from typing import Any

from mission import carrier as mc
from wire import keys
from wire.messages import REVISION, Bye, Confirm, Hello, Observation, Own, scenario_fingerprint


@dataclass(frozen=True)
class Who:
    """Which carrier of which mission: its scenario, id and index, the mission id, the world's
    fingerprint and the stages it is scheduled at."""

    scenario: Any
    cid: str
    r: int
    mission: str
    fingerprint: str
    valid: tuple

    @classmethod
    def of(cls, scenario, carrier: str, mission: str | None, valid, fingerprint: str | None = None) -> "Who":
        """Carrier ``carrier`` of ``scenario`` (a ``KeyError`` for an unknown id, checked by the
        command line) in mission ``mission`` (None: the scenario's name); ``valid``: every
        carrier's schedule, bool ``[R, N]``; ``fingerprint``: the world's (None: computed here)."""
        cid = keys.check_id(carrier, "carrier")
        r = scenario.carrier_index(cid)
        return cls(scenario, cid, r, keys.check_id(mission or keys.mission_id_from_name(scenario.name), "mission"),
                   scenario_fingerprint(scenario) if fingerprint is None else fingerprint, tuple(valid[r]))

    def handshake(self) -> mc.Handshake:
        """Its stage handshake machine at the start (:func:`mission.carrier.initial`)."""
        return mc.initial(self.cid, self.valid, self.scenario.stage_times(), self.scenario.carriers[self.r].passengers)

    def key(self, topic: str) -> str:
        """Its key of ``topic`` (docs/protocol.md, "Keys")."""
        return keys.carrier_key(self.mission, self.cid, topic)

    def observation(self, j: int, x: int | None, position, passengers_left: int, trail, counts) -> Observation:
        """Its Observation of stage j (x None: not scheduled there)."""
        return Observation(self.mission, self.cid, j, float(self.scenario.stage_time(j)), x, position,
                           passengers_left, trail, counts)

    def confirm(self, e: mc.SendConfirm, passenger: int | None) -> tuple[str, Confirm]:
        """Its Confirm of a Decision handled (``passenger``: the one released, if it deployed)."""
        return self.key("confirm"), Confirm(self.mission, self.cid, e.stage, e.deployed, e.status, e.position,
                                            e.passengers_left, passenger if e.deployed else None)

    def own(self, e: mc.SendOwn, counts) -> tuple[str, Own]:
        """Its Own: a stage it decided itself."""
        return self.key("own"), Own(self.mission, self.cid, e.stage, float(self.scenario.stage_time(e.stage)), e.x,
                                    e.deployed, e.position, e.passengers_left, counts)

    def hello(self, e: mc.SendHello, passengers_left: int, epoch: int) -> tuple[str, Hello]:
        """Its Hello (this process's pid and host; the highest epoch it heard, 1 at least)."""
        return self.key("hello"), Hello(self.mission, self.cid, os.getpid(), socket.gethostname()[:255],
                                        passengers_left, e.next_stage, self.fingerprint, max(1, epoch), REVISION)

    def bye(self, deployments, rejected, reason: str) -> tuple[str, Bye]:
        """Its Bye: its deployments, what it rejected, why it exits."""
        return self.key("bye"), Bye(self.mission, self.cid, deployments, rejected, reason)
