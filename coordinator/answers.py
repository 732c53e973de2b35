"""What a coordinator answers, built from its mission state: State (the reply to a query), the
Decision of a stage as published, the answer to a Hello (Accepted or a Refusal), and what State
tells each carrier of what this process refused or rejected of it (docs/protocol.md,
"Rejections").

:class:`Answers` is given what it needs when it is built and the mission state at each call; it
holds no wire node and calls nothing back: it returns messages, and the process puts them.
"""
from __future__ import annotations

from collections import Counter
from typing import Any

from mission import state as ms
from wire import keys
from wire.messages import (
    ACCEPTED_MAX, MAX_STATE_CARRIERS, REVISION, UNANNOUNCED_REVISION, Accepted, CarrierState, Decision, State,
    defined_in, encode, refusal,
)


class Answers:
    """A coordinator's answers.

    Attributes:
        counts: carrier id -> its messages rejected, per reason (a new Counter at every change:
            State reads it from another thread; summary.json's ``rejected``).
        refusals: carrier id -> the reason its last Hello was refused.
        served: the state State queries answer from (stored already: :meth:`serve`).

    Args:
        setup: the coordinator's :class:`coordinator.setup.MissionSetup`; epochs: its
        ``coordinator.epochs.Epochs`` (its ballot, read at each answer); config: its
        ``CoordinatorConfig`` (the clock, silence timeout and pace Accepted tells).
    """

    def __init__(self, setup, epochs, config):
        self.setup, self.epochs, self.config = setup, epochs, config
        self.counts: dict[str, Counter] = {cid: Counter() for cid in setup.ids}
        self.refusals: dict[str, str] = {}
        self.served: ms.MissionState | None = None

    def serve(self, st: ms.MissionState) -> None:
        """From now on State queries answer from ``st`` (it is stored). O(1): the reply is built
        when asked (:meth:`state_reply`), not at every event."""
        self.served = st

    def decision(self, st: ms.MissionState, j: int) -> Decision:
        """The Decision of stage j in ``st``, as published (with this process's ballot)."""
        d = st.decisions[j]
        return Decision(self.setup.mission, j, self.setup.spec.stage_times[j], d.deploy, d.planning_ms,
                        self.epochs.epoch, passengers=d.passengers, coordinator=self.epochs.ident)

    def state_reply(self, parameters: dict | None = None) -> bytes:
        """The encoded State a query gets (docs/protocol.md, "State"): ``?carrier=<id>`` lists
        that carrier only; an unscoped query lists every carrier of a mission of at most
        MAX_STATE_CARRIERS carriers, none of a larger one. Runs in the queryable's thread on an
        immutable snapshot (:attr:`served`)."""
        st, setup = self.served, self.setup
        assert st is not None, "State is served once the mission state is recovered"
        asked = keys.asked_revision(parameters, REVISION, UNANNOUNCED_REVISION)
        wanted = (parameters or {}).get("carrier")
        if wanted is not None:
            ids = [wanted] if setup.spec.has(wanted) else []
        else:
            ids = list(setup.ids) if len(setup.ids) <= MAX_STATE_CARRIERS else []
        carriers = tuple(sorted((cid, self._carrier_state(st, cid)) for cid in ids))
        last = self.decision(st, st.next_stage - 1) if (st.next_stage - 1) in st.decisions else None
        return encode(State(
            mission=setup.mission, next_stage=st.next_stage, stages=setup.n_stages, fingerprint=setup.fingerprint,
            ended=st.ended, carriers=carriers, last_decision=last, epoch=self.epochs.epoch, revision=REVISION,
            coordinator=self.epochs.ident), asked)

    def _carrier_state(self, st: ms.MissionState, cid: str) -> CarrierState:
        """One carrier's entry: its deployments as the planner sees them (its accounts, its
        Confirms, the decisions nobody answered)."""
        deployments = st.deployments_of(cid)
        left = self.setup.spec.passengers[self.setup.spec.index(cid)] - len(deployments)
        refused = None if cid in st.accepted else self.refusals.get(cid, "world-mismatch" if cid in st.refused else None)
        return CarrierState(int(left), tuple(deployments), cid in st.live, refused,
                            tuple(sorted(self.counts[cid].items())))

    def rejected(self, cid: str | None, reason: str) -> None:
        """A message of carrier ``cid`` was rejected for ``reason``: State tells it."""
        if cid in self.counts:
            self.counts[cid] = self.counts[cid] + Counter({reason: 1})  # a new value: State reads it from another thread

    def hello(self, st: ms.MissionState, cid: str, revision: int, refused: ms.Refuse | None = None
              ) -> tuple[str, Any, int] | None:
        """The answer to carrier ``cid``'s Hello (docs/protocol.md, "Refusal", "Accepted"), in the
        revision it announced, as (key, message, revision); None: none (Accepted is revision 3
        and later; earlier carriers learn it from Decisions). A Refusal to an earlier revision's
        carrier says ``world-mismatch``, the only reason it has."""
        revision = min(revision, REVISION)
        setup = self.setup
        if refused is not None:
            if cid in self.counts and cid not in st.accepted:
                self.refusals[cid] = refused.reason
            return keys.refusal_key(setup.mission, cid), refusal(
                setup.mission, cid, refused.reason, refused.fingerprint, setup.fingerprint, refused.detail,
                revision), revision
        self.refusals.pop(cid, None)
        # The mission's clock (revision 4): a carrier times its waits by the coordinator's.
        answer = Accepted(setup.mission, cid, setup.fingerprint, st.accepted[cid].next_stage, st.next_stage,
                          REVISION, self.epochs.epoch, self.config.clock,
                          min(float(self.config.silence_timeout_s), ACCEPTED_MAX),
                          min(float(self.config.realtime), ACCEPTED_MAX), coordinator=self.epochs.ident)
        if not defined_in(answer, revision):
            return None
        return keys.accepted_key(setup.mission, cid), answer, revision
