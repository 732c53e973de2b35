"""A seeded communication model: which messages arrive, and when.

Pure numpy. A :class:`CommsSpec` says how unreliable the links are; :func:`realise` draws, once
per mission, the fate of every message the fleet may send, from a stream derived from the
mission's root seed alone (``SeedSequence(seed, spawn_key=(COMMS_SPAWN_KEY,))``), so every
planner run with the same seed meets exactly the same deliveries (common random numbers).

Messages (one per kind, sender, receiver and stage ``j``):

* ``observation`` — sent by carrier ``a`` at stage ``j`` before anyone decides, to every other
  carrier and to the coordinator. It carries ``a``'s whole history: observations at stages ``<= j``
  and deployments at stages ``< j``.
* ``intent`` — sent by carrier ``a`` at stage ``j`` after it decided, to every other carrier: its
  history including the stage-``j`` deployment, and (decentralised planners) its intent.
* ``decision`` — sent by the coordinator at stage ``j`` to carrier ``r``: the stage-``j`` decision.

Each message is dropped independently with probability ``loss``; a delivered message arrives
``delay`` stages late: an observation or decision sent at ``j`` is usable at stage ``j + delay``,
an intent at ``j + 1 + delay`` (it is sent after stage ``j``'s decisions). A decision that arrives
after its stage is useless (the carrier falls back). With ``groups``, messages between carriers of
different groups are always dropped, and the coordinator hears (and is heard by) the first group
only. A carrier always "hears" itself. ``CommsSpec()`` (no loss, no delay, one group) delivers
everything at once: every planner then behaves exactly as with the central loop
:func:`planner.online.run_online`.

:class:`LinkComms` is the same model derived from the geometry: the link model's predicted
connectivity at every stage (who can hear whom, and how likely: world/linkplan.py computes it
from the stage positions, the walls and planner/links.py; this module takes it as data). A
message sent at stage j from a to b is delivered with the predicted probability of that pair at
stage j, late by its predicted delay. :func:`contact` gives any model's prediction as one array,
which the planners read to plan for the gaps the geometry will make.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Spawn key of the communication stream under the mission's root seed (``"comm"`` in ASCII;
#: stage streams use ``(j,)`` with ``j`` a stage index, far below it).
COMMS_SPAWN_KEY = 0x636F6D6D
#: Arrival stage of a message that never arrives.
NEVER = np.iinfo(np.int64).max // 2


@dataclass(frozen=True)
class CommsSpec:
    """How messages fare.

    Attributes:
        loss: probability in [0, 1] that any one message is dropped.
        delay: stages (>= 0) every delivered message is late by.
        groups: carrier index groups that hear each other (``()``: everyone together). A carrier
            listed in no group is alone; the coordinator is with the first group.
    """

    loss: float = 0.0
    delay: int = 0
    groups: tuple[tuple[int, ...], ...] = ()

    def __post_init__(self):
        if not isinstance(self.loss, (int, float)) or not 0.0 <= float(self.loss) <= 1.0:
            raise ValueError(f"message loss must be a probability in [0, 1], got {self.loss!r}")
        if isinstance(self.delay, bool) or not isinstance(self.delay, (int, np.integer)) or self.delay < 0:
            raise ValueError(f"message delay must be an integer >= 0 (stages), got {self.delay!r}")
        seen = set()
        for group in self.groups:
            for r in group:
                if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 0:
                    raise ValueError(f"groups: expected carrier indices >= 0, found {r!r}")
                if r in seen:
                    raise ValueError(f"groups: carrier {r} is listed twice")
                seen.add(r)

    @property
    def perfect(self) -> bool:
        """Whether every message arrives at once (the central loop's assumption): no loss, no
        delay, no groups (a groups list, even of one group, is checked against the instance)."""
        return self.loss == 0 and self.delay == 0 and not self.groups

    def check(self, n_carriers: int) -> None:
        """Raise ValueError when a group names a carrier outside ``0..n_carriers - 1``."""
        for group in self.groups:
            for r in group:
                if r >= n_carriers:
                    raise ValueError(f"groups: carrier {r} outside 0..{n_carriers - 1}")

    def group_of(self, n_carriers: int) -> np.ndarray:
        """int64 ``[R + 1]``: group label of every carrier, the coordinator last (label 0 = first
        group; unlisted carriers get labels of their own)."""
        self.check(n_carriers)
        if not self.groups:
            return np.zeros(n_carriers + 1, dtype=np.int64)
        label = np.full(n_carriers + 1, -1, dtype=np.int64)
        for g, group in enumerate(self.groups):
            label[list(group)] = g
        label[n_carriers] = 0
        alone = np.flatnonzero(label < 0)
        label[alone] = len(self.groups) + np.arange(len(alone))
        return label


#: Index of the coordinator in a connectivity matrix (world.relays.stage_connectivity's layout:
#: 0 the base, 1 + r carrier r).
BASE = 0


@dataclass(frozen=True, eq=False)
class LinkComms:
    """How messages fare when the link model decides, stage by stage (known before the mission).

    Attributes:
        probability: float ``[N, R + 1, R + 1]``: delivery probability at stage j of a message
            from participant a to b — index :data:`BASE` (0) the coordinator, 1 + r carrier r;
            NaN where a carrier is not in the mission at the stage (it sends and hears nothing);
            the diagonal is not read (a carrier always hears itself).
        delay: int64 ``[N, R + 1, R + 1]`` or None: stages a delivered message is late by (None:
            on time).
    """

    probability: np.ndarray
    delay: np.ndarray | None = None

    def __post_init__(self):
        p = np.asarray(self.probability, dtype=float)
        if p.ndim != 3 or p.shape[1] != p.shape[2] or p.shape[1] < 1:
            raise ValueError(f"link probabilities: expected an array [N, R + 1, R + 1], found shape {p.shape}")
        finite = p[np.isfinite(p)]
        if ((finite < 0) | (finite > 1)).any() or np.isinf(p).any():
            raise ValueError("link probabilities: expected probabilities in [0, 1] (NaN: carrier not in the mission)")
        p = p.copy()
        p.setflags(write=False)
        object.__setattr__(self, "probability", p)
        if self.delay is not None:
            d = np.asarray(self.delay)
            if d.shape != p.shape or not np.issubdtype(d.dtype, np.integer) or (d < 0).any():
                raise ValueError(f"link delays: expected integers >= 0 (stages) of shape {p.shape}, "
                                 f"found {d.dtype} of shape {d.shape}")
            d = d.astype(np.int64)
            d.setflags(write=False)
            object.__setattr__(self, "delay", d)

    @property
    def perfect(self) -> bool:
        """Whether every message arrives at once."""
        p = np.nan_to_num(self.probability, nan=1.0)
        return bool((p == 1.0).all() and (self.delay is None or not self.delay.any()))

    def check(self, n_carriers: int, n_stages: int | None = None) -> None:
        """Raise ValueError when the arrays do not have ``R + 1`` participants (and ``N`` stages)."""
        n, k, _ = self.probability.shape
        if k != n_carriers + 1 or (n_stages is not None and n != n_stages):
            raise ValueError(f"link probabilities: expected shape [{n_stages if n_stages is not None else 'N'}, "
                             f"{n_carriers + 1}, {n_carriers + 1}] (stages, base + carriers), found {self.probability.shape}")

    def stage_delay(self) -> np.ndarray:
        """int64 ``[N, R + 1, R + 1]``: the delays (zeros when None)."""
        return np.zeros(self.probability.shape, dtype=np.int64) if self.delay is None else self.delay


def contact(comms: "CommsSpec | LinkComms", n_carriers: int, n_stages: int) -> np.ndarray:
    """float ``[N, R + 1, R + 1]``: the probability, known before the mission, that a message
    sent at stage j from participant a reaches b within the stage (index :data:`BASE` the
    coordinator, 1 + r carrier r; 1 on the diagonal; 0 where a carrier is not in the mission or
    messages are late). The planners' prediction of who will hear whom."""
    R, N = n_carriers, n_stages
    if isinstance(comms, LinkComms):
        comms.check(R, N)
        out = np.nan_to_num(comms.probability, nan=0.0) * (comms.stage_delay() == 0)
    else:
        label = comms.group_of(R)
        label = np.concatenate([label[R:], label[:R]])  # the coordinator first
        same = (label[:, None] == label[None, :]).astype(float)
        out = np.broadcast_to(same * (1.0 - comms.loss) * (comms.delay == 0), (N, R + 1, R + 1)).copy()
    out[:, np.arange(R + 1), np.arange(R + 1)] = 1.0
    return out


def parse_groups(text: str) -> tuple[tuple[int, ...], ...]:
    """``"0,1/2,3"`` -> ``((0, 1), (2, 3))``: groups separated by ``/``, carriers by ``,``.

    Raises:
        ValueError: one line, on anything else (empty groups, non-integers, repeats).
    """
    groups = []
    for part in str(text).split("/"):
        try:
            group = tuple(int(v) for v in part.split(","))
        except ValueError:
            raise ValueError(f"expected groups like 0,1/2,3 (carrier indices), found {text!r}") from None
        if any(r < 0 for r in group):
            raise ValueError(f"expected carrier indices >= 0, found {text!r}")
        groups.append(group)
    flat = [r for g in groups for r in g]
    if len(flat) != len(set(flat)):
        raise ValueError(f"expected every carrier in at most one group, found {text!r}")
    return tuple(groups)


@dataclass(frozen=True, eq=False)
class Deliveries:
    """The realised fate of every message of one mission.

    Attributes:
        observation: int64 ``[R, R + 1, N]``: stage at which carrier ``a``'s stage-``j``
            observation message reaches receiver ``b`` (the coordinator is receiver ``R``), or
            :data:`NEVER`.
        intent: int64 ``[R, R, N]``: stage at which ``a``'s stage-``j`` intent message reaches ``b``.
        decision: int64 ``[R, N]``: stage at which the coordinator's stage-``j`` decision reaches
            carrier ``r``.
    """

    spec: "CommsSpec | LinkComms"
    observation: np.ndarray
    intent: np.ndarray
    decision: np.ndarray


def realise(spec: "CommsSpec | LinkComms", n_carriers: int, n_stages: int, seed: int) -> Deliveries:
    """Draw the fate of every message of a mission with root seed ``seed``.

    Draw order (fixed): uniforms for observation ``[R, R + 1, N]``, intent ``[R, R, N]``, then
    decision ``[R, N]`` messages; a message is dropped when its uniform is below ``loss``
    (:class:`LinkComms`: delivered when its uniform is below the pair's probability at the stage
    it is sent).
    """
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(COMMS_SPAWN_KEY,)))
    R, N = n_carriers, n_stages
    if isinstance(spec, LinkComms):
        return _realise_links(spec, R, N, rng)
    label = spec.group_of(R)
    stages = np.arange(N)
    u_obs = rng.random((R, R + 1, N))
    u_int = rng.random((R, R, N))
    u_dec = rng.random((R, N))
    same = label[:R, None] == label[None, :]  # [R, R + 1]
    ok_obs = (u_obs >= spec.loss) & same[:, :, None]
    ok_int = (u_int >= spec.loss) & same[:, :R, None]
    ok_dec = (u_dec >= spec.loss) & same[:, R][:, None]
    own = np.eye(R, dtype=bool)[:, :, None]
    ok_obs[:, :R] |= own
    ok_int |= own
    observation = np.where(ok_obs, stages + spec.delay, NEVER).astype(np.int64)
    intent = np.where(ok_int, stages + 1 + spec.delay, NEVER).astype(np.int64)
    # A carrier knows its own history at once.
    observation[:, :R] = np.where(own, stages, observation[:, :R])
    intent = np.where(own, stages + 1, intent)
    decision = np.where(ok_dec, stages + spec.delay, NEVER).astype(np.int64)
    for arr in (observation, intent, decision):
        arr.setflags(write=False)
    return Deliveries(spec, observation, intent, decision)


def _realise_links(spec: LinkComms, R: int, N: int, rng: np.random.Generator) -> Deliveries:
    """:func:`realise` of a :class:`LinkComms` (the same draws, the pairs' own probabilities)."""
    spec.check(R, N)
    stages = np.arange(N)
    p = np.nan_to_num(spec.probability, nan=0.0)        # [N, R + 1, R + 1], base first
    delay = spec.stage_delay()
    order = np.r_[1:R + 1, BASE]                         # receiver index b of Deliveries -> participant
    send = np.arange(1, R + 1)
    p_obs = p[:, send][:, :, order].transpose(1, 2, 0)   # [R, R + 1, N]
    d_obs = delay[:, send][:, :, order].transpose(1, 2, 0)
    p_int = p[:, send][:, :, send].transpose(1, 2, 0)    # [R, R, N]
    d_int = delay[:, send][:, :, send].transpose(1, 2, 0)
    p_dec = p[:, BASE, send].T                           # [R, N]
    d_dec = delay[:, BASE, send].T
    u_obs = rng.random((R, R + 1, N))
    u_int = rng.random((R, R, N))
    u_dec = rng.random((R, N))
    observation = np.where(u_obs < p_obs, stages + d_obs, NEVER).astype(np.int64)
    intent = np.where(u_int < p_int, stages + 1 + d_int, NEVER).astype(np.int64)
    decision = np.where(u_dec < p_dec, stages + d_dec, NEVER).astype(np.int64)
    own = np.eye(R, dtype=bool)[:, :, None]
    observation[:, :R] = np.where(own, stages, observation[:, :R])
    intent = np.where(own, stages + 1, intent)
    for arr in (observation, intent, decision):
        arr.setflags(write=False)
    return Deliveries(spec, observation, intent, decision)
