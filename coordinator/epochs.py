"""Split brain on the coordinator's side (docs/fleet.md, "Split brain"): claiming the mission
(a live coordinator of it refuses this one, or a standby waits for its token to vanish), the
epoch this process takes (above every one used before: mission.db's and a live primary's), and
the reaction to a newer epoch (a carrier heard it, a Decision of it, mission.db records it).

The carrier's rule (a lower epoch's Decision is ``deposed``) is in ``mission.carrier``; what
needs a session or the store is here. :class:`Epochs` is a part of
:class:`coordinator.node.Coordinator`.
"""
from __future__ import annotations

from pathlib import Path

from mission import timers as tm
from mission.timeouts import DEFAULTS
from storage.missiondb import MissionStore, StoreBusy
from wire import keys
from wire.messages import Decision, ProtocolError, State, decode


class DuplicateCoordinator(RuntimeError):
    """Another coordinator's liveliness token for this mission is live (and this one is no
    standby): refuse to start, before mission.db is touched."""

    def __init__(self, mission: str):
        super().__init__(f"mission {mission} already has a live coordinator; use --standby to wait for it, "
                         f"or another --mission")
        self.mission = mission


class Epochs:
    """The coordinator's claim on its mission and its epochs."""

    def _carrier_epoch(self, cid: str, epoch: int) -> None:
        """A carrier has heard a higher epoch than ours. Before this process decided a stage (it
        may have re-published the last decision) a coordinator that had that epoch is gone or out
        of our reach: take the next epoch (recorded, so a restart goes higher still) and
        re-publish. After it, a newer coordinator decides this mission: we are deposed."""
        if self.deposed_by is not None:
            return
        if self.state.next_stage > self._first_stage:
            self._deposed(epoch, f"carrier {cid} has heard it")
            return
        self.log(f"coordinator: carrier {cid} has heard epoch {epoch}; this coordinator takes epoch {epoch + 1}")
        self.epoch = epoch + 1
        self.store.raise_epoch(self.epoch)
        self._refresh_state()
        if self.state.next_stage > 0:
            self._publish_decision(self._decision(self.state.next_stage - 1))

    def _heard_decision(self, item) -> None:
        """A Decision on this mission's decision key (ours come back to us): one of a higher
        epoch means another coordinator took over (e.g. a partition healed after a standby
        took over): stop deciding, publish no End, exit (docs/fleet.md, "Split brain"). Anything
        else there is not addressed to this coordinator: ignored, not counted (carriers count it)."""
        try:
            msg = decode(item.payload, Decision)
        except ProtocolError:
            return
        if msg.mission == self.mission and msg.epoch > self.epoch:
            self._deposed(msg.epoch, "it decides")

    def _deposed(self, epoch: int, how: str) -> None:
        """Stop deciding: a coordinator of a higher epoch took over (no End, no summary.json)."""
        if self.deposed_by is not None:
            return
        self.deposed_by = epoch
        self.log(f"coordinator: deposed: a coordinator of epoch {epoch} took over mission {self.mission} ({how}; "
                 f"this one has epoch {self.epoch}); stopping without End")
        self._stop.set()

    def _claim(self) -> bool:
        """Before this coordinator declares its token: is another coordinator of the mission
        live? Not a standby: raise :class:`DuplicateCoordinator`. A standby waits while the
        primary's token is present (:func:`mission.timers.standby`), querying its State every
        ``standby_state_s`` for its epoch; returns
        False when stopped before the primary vanished, True when this process may go on."""
        alive = keys.coordinator_alive(self.mission)
        if not self.node.live_tokens(alive, DEFAULTS.liveliness_check_s):
            return True
        if not self.config.standby:
            raise DuplicateCoordinator(self.mission)
        self.known_epoch = max(self.known_epoch, 1)  # a primary lives: its epoch is 1 at least
        self.log(f"coordinator: standby: mission {self.mission} has a live coordinator; waiting for its "
                 f"liveliness token to vanish")
        asked = None
        while not self._stop.is_set():
            if tm.due(asked, self.clock(), DEFAULTS.standby_state_s):
                self._learn_epoch()
                asked = self.clock()
            present = bool(self.node.live_tokens(alive, DEFAULTS.liveliness_check_s))
            looked = self.clock()
            rule = tm.standby(present, None if present else looked, looked, DEFAULTS.standby_poll_s)
            if isinstance(rule, tm.TakeOver):
                self.log(f"coordinator: the primary's liveliness token vanished; taking over mission "
                         f"{self.mission} (it had epoch {self.known_epoch or 'unknown'})")
                return True
            self._stop.wait(rule.until - looked)
        return False

    def _open_store(self, path: Path, meta: dict) -> MissionStore:
        """mission.db, waiting while another process holds its write lock (a standby taking over
        from a primary that hangs in the middle of a write on the same disk)."""
        logged = False
        while True:
            try:
                return MissionStore(path, meta, min_epoch=self.known_epoch + 1)
            except StoreBusy as exc:
                if not logged:
                    self.log(f"coordinator: {exc}; waiting for it")
                    logged = True
                if self._stop.wait(0.5):
                    raise

    def _learn_epoch(self) -> None:
        """The primary's epoch, from its State (and the last Decision in it)."""
        for payload in self.node.query(keys.state_key(self.mission), timeout_s=DEFAULTS.state_query_s):
            try:
                state = decode(payload, State)
            except ProtocolError:
                continue
            if state.mission == self.mission:
                last = state.last_decision.epoch if state.last_decision is not None else 0
                self.known_epoch = max(self.known_epoch, state.epoch, last)
