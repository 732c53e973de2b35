"""The only place that touches zenoh sessions: a node's session, its inbox and bounded shutdown.

Invariant: zenoh callbacks only copy the sample's key and bytes (or the liveliness change, or the
query object) into a thread-safe queue; all decoding, validation and zenoh calls happen in the
node's own threads.
"""
from __future__ import annotations

import heapq
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import zenoh

from . import messages
from .zconfig import close_session, open_session


@dataclass(frozen=True)
class Inbound:
    """One item of a node's inbox.

    Attributes:
        kind: ``sample`` (a put), ``alive`` (liveliness token appeared), ``gone`` (token vanished),
            ``wake`` (no message: :meth:`Node.wake`).
        key: the key expression it arrived on.
        payload: the raw bytes (``sample`` only).
        received: when it was enqueued on the node's clock (``time.monotonic()`` unless its owner
            gives its own, e.g. a carrier's clock under a schedule's clock jump), seconds.
        wall: ``time.time()`` when it was enqueued, seconds since the epoch.
    """

    kind: str
    key: str
    payload: bytes = b""
    received: float = 0.0
    wall: float = 0.0


#: Samples one ``wake=False`` subscription holds until drained (then zenoh waits: no sample is
#: dropped). A carrier drains at least every few seconds; a peer sends a few messages per stage.
QUIET_CAPACITY = 4096


def _sample_item(sample, clock) -> Inbound:
    """The inbox item of a zenoh sample. An oversized payload is not copied: a marker one byte
    over the limit is enough for decode() to reject it as oversized."""
    payload = sample.payload
    limit = messages.MAX_PAYLOAD_BYTES
    data = payload.to_bytes() if len(payload) <= limit else b"\0" * (limit + 1)
    return Inbound("sample", str(sample.key_expr), data, clock(), time.time())


class Held:
    """Messages a :class:`wire.link_filter.LinkFilter` delayed, released in order of their due time."""

    def __init__(self):
        self.heap: list = []
        self.seq = 0

    def add(self, due: float, item) -> None:
        self.seq += 1
        heapq.heappush(self.heap, (due, self.seq, item))

    def due(self, now: float):
        """The next item due by ``now`` (monotonic s), else None."""
        if self.heap and self.heap[0][0] <= now:
            return heapq.heappop(self.heap)[2]
        return None

    def next_due(self) -> float | None:
        return self.heap[0][0] if self.heap else None


class SharedSession:
    """One zenoh session for the nodes of one process (the carriers it simulates), opened by the
    first node that needs it and closed when the last one closes.

    A session costs CPU per second of wall time even with no traffic, so a session per node
    costs a shared process that CPU once per carrier, and makes the router send every broadcast
    once per carrier instead of once per process (docs/performance.md, "Carrier CPU per stage").
    The
    protocol cannot tell: every carrier keeps its own subscriptions, publishers and liveliness
    token, undeclared when that carrier closes.

    Args:
        conf: the zenoh config of the session.
    """

    def __init__(self, conf: zenoh.Config):
        self._conf = conf
        self._lock = threading.Lock()
        self._session = None
        self._users = 0

    def acquire(self, open_timeout_s: float, stop: threading.Event | None = None):
        """The session, opened now if no node holds it (the same retries and stop as
        :func:`wire.zconfig.open_session`); every call needs one :meth:`release`."""
        with self._lock:
            if self._session is None:
                self._session = open_session(self._conf, open_timeout_s, stop=stop)
            self._users += 1
            return self._session

    def release(self, timeout_s: float) -> bool:
        """One node is done with the session; the last one closes it (bounded by ``timeout_s``)."""
        with self._lock:
            self._users -= 1
            if self._users > 0 or self._session is None:
                return True
            session, self._session = self._session, None
        return close_session(session, (), timeout_s)


class Node:
    """A zenoh session with declared entities, an inbox queue and rejection counters.

    Args:
        conf: the zenoh config (see :func:`wire.zconfig.make_config`).
        open_timeout_s: how long to keep trying to open the session.
        stop: when set, stop trying to open the session (raises :class:`wire.zconfig.OpenStopped`).
        shared: the process's :class:`SharedSession` to declare on instead of a session of the
            node's own (then ``conf`` is not used); :meth:`close` undeclares only this node's
            entities.
        links: the scenario's links applied to what arrives (:attr:`links`).
        clock: what an item's ``received`` is read on (its owner's clock: a process compares
            times of one clock only).
    """

    def __init__(self, conf: zenoh.Config | None, open_timeout_s: float = 10.0, stop: threading.Event | None = None,
                 shared: SharedSession | None = None, links=None, clock=time.monotonic):
        self._shared = shared
        self.clock = clock
        self.session = (open_session(conf, open_timeout_s, stop=stop) if shared is None
                        else shared.acquire(open_timeout_s, stop))
        self.inbox: "queue.Queue[Inbound]" = queue.Queue()
        self.rejected: Counter = Counter()
        self._logged: set[str] = set()
        self._entities: list[Any] = []
        self._publishers: dict[str, Any] = {}
        self._quiet: list[Any] = []  # subscribers with a FIFO channel (subscribe(wake=False))
        self._lock = threading.Lock()
        #: The protocol revision :meth:`put` encodes for (docs/protocol.md, "Revisions"): this
        #: code's own until the node's owner learns its peer's.
        self.revision = messages.REVISION
        #: The scenario's links applied to what arrives (:class:`wire.link_filter.LinkFilter`,
        #: given by the node's owner); None: every sample as zenoh delivers it.
        self.links = links
        self._held, self._held_quiet = Held(), Held()

    # ------------------------------------------------------------------ declarations
    def subscribe(self, key_expr: str, wake: bool = True) -> None:
        """Puts on ``key_expr`` land in the inbox as ``Inbound("sample", key, bytes)``.

        With ``wake`` False they wait instead in a zenoh FIFO channel, with no Python callback and
        no wake-up of the thread waiting in :meth:`next`, until :meth:`drain` collects them: for
        traffic a node only needs when it next looks (a carrier's peers). With dozens of
        sessions in one process, a callback and a wake-up per message cost more than the
        message (docs/performance.md, "Fleet scale")."""
        if not wake:
            sub = self.session.declare_subscriber(key_expr, zenoh.handlers.FifoChannel(QUIET_CAPACITY))
            self._entities.append(sub)
            self._quiet.append(sub)
            return
        inbox, clock = self.inbox, self.clock

        def on_sample(sample):
            try:
                inbox.put(_sample_item(sample, clock))
            except Exception:
                pass  # never raise into zenoh

        self._entities.append(self.session.declare_subscriber(key_expr, on_sample))

    def drain(self) -> list[Inbound]:
        """Every sample waiting on the ``wake=False`` subscriptions, per subscription in arrival
        order (``received`` and ``wall``: when drained); with :attr:`links`, those it lets through
        now, the ones it held when due."""
        out = []
        for sub in self._quiet:
            while True:
                sample = sub.try_recv()
                if sample is None:
                    break
                item = self._through_links(_sample_item(sample, self.clock), quiet=True)
                if item is not None:
                    out.append(item)
        if self.links is not None:
            now = time.monotonic()
            while (held := self._held_quiet.due(now)) is not None:
                out.append(held)
        return out

    def _through_links(self, item: Inbound, quiet: bool = False) -> Inbound | None:
        """``item`` if the links deliver it now; None if they drop it or hold it (then it comes
        out of :meth:`next` or :meth:`drain` when due)."""
        if self.links is None or item.kind != "sample":
            return item
        delay = self.links.delay(item.key, item.payload)
        if delay is None:
            return None
        if delay <= 0.0:
            return item
        (self._held_quiet if quiet else self._held).add(time.monotonic() + delay, item)
        return None

    def watch_liveliness(self, key_expr: str) -> None:
        """Liveliness tokens matching ``key_expr`` (existing ones included) land in the inbox as
        ``alive`` / ``gone`` items."""
        inbox, clock = self.inbox, self.clock

        def on_token(sample):
            try:
                kind = "alive" if sample.kind == zenoh.SampleKind.PUT else "gone"
                inbox.put(Inbound(kind, str(sample.key_expr), b"", clock(), time.time()))
            except Exception:
                pass

        self._entities.append(self.session.liveliness().declare_subscriber(key_expr, on_token, history=True))

    def token(self, key_expr: str) -> None:
        """Declare this node's liveliness token (it vanishes when the session or process dies)."""
        self._entities.append(self.session.liveliness().declare_token(key_expr))

    def serve(self, key_expr: str, reply_bytes) -> None:
        """Answer queries on ``key_expr`` with ``reply_bytes(parameters)`` (called in a server
        thread, must not block; ``parameters``: the selector's parameters as a dict of str, e.g.
        ``{"carrier": "c1"}`` for ``key?carrier=c1``). The zenoh callback only enqueues the
        query."""
        queries: "queue.Queue[Any]" = queue.Queue()
        stop = threading.Event()
        self._serving = (queries, stop)

        def on_query(query):
            queries.put(query)

        def server():
            while not stop.is_set():
                try:
                    query = queries.get(timeout=0.1)
                except queue.Empty:
                    continue
                try:
                    text = str(query.parameters)
                    params = dict(part.split("=", 1) if "=" in part else (part, "")
                                  for part in text.split(";") if part)
                    query.reply(key_expr, reply_bytes(params))
                except Exception:
                    pass
                finally:
                    try:
                        query.drop()
                    except Exception:
                        pass

        self._entities.append(self.session.declare_queryable(key_expr, on_query))
        self._server = threading.Thread(target=server, daemon=True, name="state-server")
        self._server.start()

    # ------------------------------------------------------------------ traffic
    def put(self, key_expr: str, message, revision: int | None = None) -> None:
        """Encode and publish one message: reliable, blocking congestion control. In zenoh-python
        1.x reliability is a property of a declared publisher (``Session.put`` has no
        ``reliability`` option), so every key gets one publisher, declared on first use.
        ``revision``: the protocol revision of its receivers (docs/protocol.md, "Revisions");
        :attr:`revision` (the peer's, once learnt; this code's own by default) when None."""
        data = messages.encode(message, self.revision if revision is None else revision)
        pub = self._publishers.get(key_expr)
        if pub is None:
            pub = self.session.declare_publisher(
                key_expr, congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE
            )
            self._publishers[key_expr] = pub
            self._entities.append(pub)
        pub.put(data)

    def put_raw(self, key_expr: str, data: bytes) -> None:
        """Publish raw bytes (tests and fuzzers), with blocking congestion control like
        :meth:`put`: zenoh's default (drop) may lose a large, fragmented payload under load."""
        self.session.put(key_expr, data, congestion_control=zenoh.CongestionControl.BLOCK)

    def query(self, key_expr: str, timeout_s: float = 2.0) -> list[bytes]:
        """Payloads of the replies to a query on ``key_expr`` (empty list when nobody answers):
        every matching queryable's (target ``ALL``), each reply kept (consolidation ``NONE``), so
        that two coordinators answering across a split brain are both heard (docs/protocol.md,
        "State")."""
        out = []
        try:
            for reply in self.session.get(key_expr, target=zenoh.QueryTarget.ALL,
                                          consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout_s):
                if reply.ok is not None:
                    out.append(reply.ok.payload.to_bytes())
        except Exception:
            pass
        if self.links is not None:  # the query and its replies cross the links (both drawn here)
            out = self._replies_through_links(str(key_expr), out)
        return out

    def _replies_through_links(self, selector: str, replies: list[bytes]) -> list[bytes]:
        """The replies the links deliver: the query goes out (its own fate and delay, the link
        being the same both ways), then each reply; the caller waits for the latest (an acoustic
        round trip takes seconds: it is waited for, not cut at the query's timeout)."""
        key = selector.split("?", 1)[0]
        out_delay = self.links.delay(key, selector.encode())
        if out_delay is None:
            return []
        kept, wait = [], 0.0
        for data in replies:
            delay = self.links.delay(key, data)
            if delay is not None:
                kept.append(data)
                wait = max(wait, delay)
        time.sleep(out_delay + wait)
        return kept

    def live_tokens(self, key_expr: str, timeout_s: float) -> list[str]:
        """Key expressions of the liveliness tokens matching ``key_expr`` that exist right now
        anywhere this session reaches (a liveliness ``get``; waits at most ``timeout_s`` seconds,
        usually milliseconds). How a process learns, before declaring its own token, that
        another process already holds it (docs/fleet.md, "Split brain")."""
        found = []
        for reply in self.session.liveliness().get(key_expr, timeout=timeout_s):
            if reply.ok is not None:
                found.append(str(reply.ok.key_expr))
        return sorted(set(found))

    def pending(self) -> bool:
        """Whether an inbox item is waiting (or a held one is due)."""
        due = self._held.next_due()
        return not self.inbox.empty() or (due is not None and due <= time.monotonic())

    def next(self, timeout_s: float) -> Inbound | None:
        """The next inbox item, or None after ``timeout_s`` seconds (with :attr:`links`: the next
        one they let through, a held one when it is due)."""
        if self.links is None:
            try:
                return self.inbox.get(timeout=max(0.0, timeout_s))
            except queue.Empty:
                return None
        deadline = time.monotonic() + max(0.0, timeout_s)
        while True:
            now = time.monotonic()
            held = self._held.due(now)
            if held is not None:
                return held
            wait = deadline - now
            due = self._held.next_due()
            if due is not None:
                wait = min(wait, due - now)
            try:
                item = self.inbox.get(timeout=max(0.0, wait)) if wait > 0 else self.inbox.get_nowait()
            except queue.Empty:
                if time.monotonic() >= deadline and (due is None or due > deadline):
                    return None
                continue
            item = self._through_links(item)
            if item is not None:
                return item

    def wake(self) -> None:
        """Wake whoever waits in :meth:`next` (an ``Inbound("wake", "")`` item, which carries
        nothing): how a stop request reaches a node that sleeps until its next message."""
        self.inbox.put(Inbound("wake", "", b"", time.monotonic(), time.time()))

    def reject(self, reason: str, detail: str, log) -> None:
        """Count a rejected message; log the first one of each reason."""
        self.rejected[reason] += 1
        if reason not in self._logged:
            self._logged.add(reason)
            log(f"rejected a message ({reason}): {detail} [further '{reason}' rejections are only counted]")

    def close(self, timeout_s: float = 3.0) -> bool:
        """Undeclare everything and close the session, bounded by ``timeout_s`` seconds."""
        serving = getattr(self, "_serving", None)
        if serving:
            serving[1].set()
        if self._shared is None:
            return close_session(self.session, list(reversed(self._entities)), timeout_s)
        undeclared = close_session(None, list(reversed(self._entities)), timeout_s)
        return self._shared.release(timeout_s) and undeclared
