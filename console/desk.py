"""The operator's desk: every action, from the page or from the mission's operator key, goes
through it to the coordinator's loop, and each sender gets its answer.

An action for a stage that is not being decided (already decided, not yet open, the mission
over) is refused at once from the latest mission state (:func:`mission.operator_rules.refusal`);
the others wait in a queue that the stage's hold drains (:mod:`console.hold`), where the same
rule is checked again on the state the action is applied to. Actions on the Zenoh key carry the
mission's operator credential (``operator.token`` in the results directory); the network's
access control (docs/security.md) decides who may publish there at all.
"""
from __future__ import annotations

import hmac
import os
import queue
import secrets
import threading
import time
from pathlib import Path
from typing import Callable

from mission import events as ev
from mission.operator_rules import refusal

#: How long a sender's answer waits for the coordinator's loop (s): the loop drains the desk
#: every poll while a stage is held; outside a hold the action waits for the next one.
ANSWER_WAIT_S = 30.0
#: Zenoh actions queued for the key's worker at most (more are dropped: a flood never grows memory).
KEY_QUEUE_MAX = 256


class Ticket:
    """One action's answer: ``{"accepted": bool, "reason": str, "detail": str}`` once settled."""

    def __init__(self):
        self._done = threading.Event()
        self.answer: dict | None = None

    def settle(self, accepted: bool, reason: str = "", detail: str = "") -> None:
        if self.answer is None:
            self.answer = {"accepted": bool(accepted), "reason": reason, "detail": detail}
        self._done.set()

    def wait(self, timeout_s: float) -> dict:
        """The answer, or a refusal ``timeout`` when the coordinator did not take it in time."""
        if not self._done.wait(timeout_s):
            return {"accepted": False, "reason": "timeout",
                    "detail": f"no answer from the coordinator within {timeout_s:g} s"}
        return self.answer


def new_token(out_dir) -> str:
    """The mission's operator credential: read from ``operator.token`` in ``out_dir`` (a resumed
    mission keeps it), else made and written there, readable by its owner only."""
    path = Path(out_dir) / "operator.token"
    if path.is_file():
        text = path.read_text().strip()
        if text:
            return text
    token = secrets.token_urlsafe(24)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    return token


class Desk:
    """Actions in, answers out, and what the page shows.

    Args:
        state_of: the coordinator's latest :class:`mission.state.MissionState` (immutable; read
            from the server's threads).
        token: the mission's operator credential (:func:`new_token`).
        view: the :class:`console.view.ConsoleView` that turns a state into what the page shows.
        log: a callable taking one line.
    """

    def __init__(self, state_of: Callable, token: str, view, log=print):
        self.state_of, self.token, self.view, self.log = state_of, token, view, log
        self._queue: "queue.SimpleQueue[tuple[ev.OperatorAction, Ticket]]" = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._hold: dict | None = None  # the stage being held (console.hold), None between holds
        self._holds = 0  # counts every change of the hold
        self._cached: tuple = (None, None)  # (key, snapshot): the last one built
        self._answers: list[dict] = []  # the last answers, newest last (the page shows them)
        self._stop = threading.Event()
        self._key_items: "queue.Queue" = queue.Queue(KEY_QUEUE_MAX)

    # ------------------------------------------------------------------ actions
    def submit(self, stage: int, action: str, carrier: str | None, operator: str) -> Ticket:
        """Take one action; its :class:`Ticket` settles when the coordinator took or refused it."""
        e = ev.OperatorAction(int(stage), str(action), carrier, str(operator), time.time())
        ticket = Ticket()
        refused = refusal(self.state_of(), e)
        if refused is not None:
            self._settle(ticket, e, False, *refused)
        else:
            self._queue.put((e, ticket))
        return ticket

    def drain(self) -> list[tuple[ev.OperatorAction, Ticket]]:
        """The actions waiting for the coordinator's loop, oldest first."""
        out = []
        while True:
            try:
                out.append(self._queue.get_nowait())
            except queue.Empty:
                return out

    def answer(self, ticket: Ticket, e: ev.OperatorAction, accepted: bool, reason: str = "", detail: str = "") -> None:
        """The coordinator's answer to ``e``."""
        self._settle(ticket, e, accepted, reason, detail)

    def _settle(self, ticket, e, accepted, reason="", detail="") -> None:
        ticket.settle(accepted, reason, detail)
        what = e.action + (f" {e.carrier}" if e.carrier else "")
        with self._lock:
            self._answers = (self._answers + [{"stage": e.stage, "action": what, "operator": e.operator,
                                               "accepted": accepted, "reason": reason, "detail": detail,
                                               "at": e.at}])[-8:]
        if not accepted:
            self.log(f"coordinator: stage {e.stage}: operator {e.operator}'s {what} refused ({reason}: {detail})")

    # ------------------------------------------------------------------ the page's view
    def show(self, hold: dict | None) -> None:
        """The stage being held from now on (its recommendation, reasons, constraints and
        deadline), or None: no stage is held (the coordinator's loop calls it)."""
        with self._lock:
            self._hold, self._holds = hold, self._holds + 1

    def snapshot(self) -> dict:
        """What the page shows now: built from the coordinator's latest state when it or the
        hold changed since the last one (:meth:`console.view.ConsoleView.snapshot`)."""
        state = self.state_of()
        with self._lock:
            hold, holds, answers = self._hold, self._holds, list(self._answers)
        key = (id(state), holds)
        cached_key, snap = self._cached
        if cached_key != key or snap is None:
            snap = dict(self.view.snapshot(state, hold), version=f"{key[0]}-{key[1]}")
            self._cached = (key, snap)
        return dict(snap, answers=answers, now=time.time())

    # ------------------------------------------------------------------ the Zenoh key
    def listen(self, node, mission: str) -> None:
        """Take actions from ``marsupial/<m>/operator/*/action`` on ``node``'s session and answer
        each on ``marsupial/<m>/coordinator/operator/<op>`` ([P-12.4]; docs/protocol.md,
        "Operator actions"). The subscriber's callback only queues the bytes (no Zenoh call in a
        callback); a worker thread decodes, checks the credential [P-12.2] and answers."""
        from wire import keys

        items = self._key_items

        def on_sample(sample):
            try:
                items.put_nowait(bytes(sample.payload.to_bytes()))
            except Exception:
                pass  # full or undecodable: dropped, never raised into zenoh

        self._subscriber = node.session.declare_subscriber(keys.operator_actions_pattern(mission), on_sample)
        threading.Thread(target=self._key_worker, args=(node, mission), daemon=True, name="operator-key").start()

    def _key_worker(self, node, mission: str) -> None:
        from wire import keys
        from wire.messages import OperatorAction, OperatorAnswer, ProtocolError, decode

        while not self._stop.is_set():
            try:
                data = self._key_items.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                msg = decode(data, OperatorAction)
            except ProtocolError as exc:
                self.log(f"coordinator: an operator action rejected ({exc.reason}: {exc})")
                continue
            if msg.mission != mission:
                continue
            if not hmac.compare_digest(msg.token.encode(), self.token.encode()):
                answer = {"accepted": False, "reason": "not-authorised",
                          "detail": "the action does not carry the mission's operator credential"}
                self.log(f"coordinator: an operator action from {msg.operator} refused (not-authorised)")
            else:
                answer = self.submit(msg.stage, msg.action, msg.carrier, msg.operator).wait(ANSWER_WAIT_S)
            try:
                node.put(keys.operator_answer_key(mission, msg.operator),
                         OperatorAnswer(mission, msg.operator, msg.seq, msg.stage, answer["accepted"],
                                        answer["reason"][:40], answer["detail"][:200]))
            except Exception as exc:  # a closing session: the answer is lost, the mission goes on
                self.log(f"coordinator: operator answer not sent ({type(exc).__name__})")

    def close(self) -> None:
        self._stop.set()
        sub = getattr(self, "_subscriber", None)
        if sub is not None:
            try:
                sub.undeclare()
            except Exception:
                pass
