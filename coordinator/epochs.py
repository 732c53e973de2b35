"""Split brain on the coordinator's side (docs/fleet.md, "Split brain"): opening the session and
claiming the mission (a live coordinator of it refuses this one, or a standby waits for its token
to vanish), the epoch this process takes (above every one used before: mission.db's and a live
primary's), and the reaction to a newer epoch (a Decision of it, mission.db records it).

Authority comes from coordinators only (docs/protocol.md [P-7.3]): what a carrier says of an
epoch (its Hello's) is a claim, logged and counted, never adopted: it neither raises this
coordinator's epoch nor deposes it.

The carrier's rule (a lower epoch's Decision is ``deposed``) is in ``mission.carrier``; what
needs a session or the store is here. :class:`Epochs` is a collaborator of
:class:`coordinator.node.Coordinator`, given what it needs.
"""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

from mission import timers as tm
from mission.ballot import Ballot
from mission.timeouts import DEFAULTS
from storage.missiondb import MissionStore, StoreBusy, StoreFenced
from wire import keys
from wire.messages import Decision, ProtocolError, State, decode


def default_ident() -> str:
    """A coordinator id unique to this process: ``<host>-<pid>``, made an id (wire.keys.ID_PATTERN)."""
    import os
    import re
    import socket

    host = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname()).lstrip(".-") or "host"
    return f"{host[:50]}-{os.getpid()}"


class DuplicateCoordinator(RuntimeError):
    """Another coordinator's liveliness token for this mission is live (and this one is no
    standby): refuse to start, before mission.db is touched."""

    def __init__(self, mission: str):
        super().__init__(f"mission {mission} already has a live coordinator; use --standby to wait for it, "
                         f"or another --mission")
        self.mission = mission


class Epochs:
    """This coordinator's claim on its mission and its epochs.

    Attributes:
        ident: this process's coordinator id: with its epoch, its ballot (:mod:`mission.ballot`).
        epoch: this process's epoch (set when it opens mission.db; nothing raises it after).
        known: the highest epoch a live primary reported while this one stood by.
        first_stage: the first stage this process decides.
        claims: per carrier, the highest epoch above this one its Hellos reported (not adopted).
        deposed_by: the epoch of a newer coordinator that deposed this one (None while not).

    Args:
        mission: the mission id; log: a callable taking one line; stop: the coordinator's stop
        request (set when it is deposed); clock: what its standby wait reads; ident: its id.
    """

    def __init__(self, mission: str, log, stop, clock, ident: str):
        self.mission, self.log, self._stop, self.clock, self.ident = mission, log, stop, clock, ident
        self.epoch = 1
        self.known = 0
        self.first_stage = 0
        self.deposed_by: int | None = None
        self.claims: dict[str, int] = {}

    @property
    def ballot(self) -> Ballot:
        """This coordinator's authority (docs/protocol.md [P-7.1]): its epoch and its id."""
        return Ballot(self.epoch, self.ident)

    def carrier_claimed(self, cid: str, epoch: int) -> None:
        """A carrier's Hello reports a higher epoch than this coordinator's. A carrier's message
        never changes who decides [P-7.3]: not adopted, not a deposition; the highest claim per
        carrier is kept for the record (summary.json ``denials``) and its first one logged."""
        if epoch > self.claims.get(cid, 0):
            if cid not in self.claims:
                self.log(f"coordinator: carrier {cid} reports epoch {epoch} (this coordinator's is {self.epoch}); "
                         f"a carrier's message does not change who decides: not adopted")
            self.claims[cid] = epoch

    def decision_heard(self, payload: bytes) -> None:
        """A Decision on this mission's decision key (ours come back to us): one of a higher
        ballot means another coordinator took over (e.g. a partition healed after a standby
        took over): stop deciding, publish no End, exit (docs/fleet.md, "Split brain"). Anything
        else there is not addressed to this coordinator: ignored, not counted (carriers count it)."""
        try:
            msg = decode(payload, Decision)
        except ProtocolError:
            return
        theirs = Ballot(msg.epoch, msg.coordinator)
        if msg.mission == self.mission and self.ballot.below(theirs):
            self.deposed(theirs, "it decides")

    def deposed(self, ballot: Ballot, how: str) -> None:
        """Stop deciding: a coordinator of a higher ballot took over (no End, no summary.json)."""
        if self.deposed_by is not None:
            return
        self.deposed_by = ballot.epoch
        tie = f", its id {ballot.coordinator!r} above this one's {self.ident!r}" if ballot.epoch == self.epoch else ""
        self.log(f"coordinator: deposed: a coordinator of epoch {ballot.epoch} took over mission {self.mission} ({how}; "
                 f"this one has epoch {self.epoch}{tie}); stopping without End")
        self._stop.set()

    @contextmanager
    def fencing(self):
        """Around a decision's write: mission.db refuses it when it records a newer epoch than
        ours (:class:`storage.missiondb.StoreFenced`, checked under the write lock in the
        decision's transaction: a standby took over on our disk while we were cut off or
        paused): deposed (:meth:`deposed`), nothing of it written or published."""
        try:
            yield
        except StoreFenced as exc:
            self.deposed(exc.ballot, "mission.db records it")

    def session(self, open_node, standby: bool) -> tuple:
        """The coordinator's Zenoh session (``open_node()`` opens it; it raises
        ``wire.zconfig.OpenStopped`` when stopped first) and the claim on the mission
        (:meth:`claim`): (node, True) when this process may go on, (None, True) when stopped
        before the session opened, (None, False) when a standby stopped while the primary lived
        (its session closed)."""
        from wire.zconfig import OpenStopped

        node = None
        if not self._stop.is_set():
            try:
                node = open_node()
            except OpenStopped:
                node = None
        if node is None:
            return None, True
        try:
            claimed = self.claim(node, standby)
        except BaseException:
            node.close(DEFAULTS.close_s)
            raise
        if not claimed:
            node.close(DEFAULTS.close_s)
            return None, False
        return node, True

    def claim(self, node, standby: bool) -> bool:
        """Before this coordinator declares its token on ``node``: is another coordinator of the
        mission live? Not a ``standby``: raise :class:`DuplicateCoordinator`. A standby waits
        while the primary's token is present (:func:`mission.timers.standby`), querying its State
        every ``standby_state_s`` for its epoch; returns False when stopped before the primary
        vanished, True when this process may go on."""
        alive = keys.coordinator_alive(self.mission)
        if not node.live_tokens(alive, DEFAULTS.liveliness_check_s):
            return True
        if not standby:
            raise DuplicateCoordinator(self.mission)
        self.known = max(self.known, 1)  # a primary lives: its epoch is 1 at least
        self.log(f"coordinator: standby: mission {self.mission} has a live coordinator; waiting for its "
                 f"liveliness token to vanish")
        asked = None
        while not self._stop.is_set():
            if tm.due(asked, self.clock(), DEFAULTS.standby_state_s):
                self._learn(node)
                asked = self.clock()
            present = bool(node.live_tokens(alive, DEFAULTS.liveliness_check_s))
            looked = self.clock()
            rule = tm.standby(present, None if present else looked, looked, DEFAULTS.standby_poll_s)
            if isinstance(rule, tm.TakeOver):
                self.log(f"coordinator: the primary's liveliness token vanished; taking over mission "
                         f"{self.mission} (it had epoch {self.known or 'unknown'})")
                return True
            self._stop.wait(rule.until - looked)
        return False

    def open_store(self, path: Path, meta: dict) -> MissionStore:
        """mission.db with this process's epoch, higher than every one used before for this
        mission (mission.db's and the one a primary reported while this process stood by),
        waiting while another process holds its write lock (a standby taking over from a
        primary that hangs in the middle of a write on the same disk)."""
        logged = False
        while True:
            try:
                store = MissionStore(path, meta, min_epoch=self.known + 1, coordinator=self.ident)
                self.epoch = store.epoch
                return store
            except StoreBusy as exc:
                if not logged:
                    self.log(f"coordinator: {exc}; waiting for it")
                    logged = True
                if self._stop.wait(0.5):
                    raise

    def _learn(self, node) -> None:
        """The primary's epoch, from its State (and the last Decision in it)."""
        for payload in node.query(keys.state_key(self.mission), timeout_s=DEFAULTS.state_query_s):
            try:
                state = decode(payload, State)
            except ProtocolError:
                continue
            if state.mission == self.mission:
                last = state.last_decision.epoch if state.last_decision is not None else 0
                self.known = max(self.known, state.epoch, last)
