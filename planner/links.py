"""The link model, pure part: which message arrives, when, and which is lost (docs/scenario.md,
"Links").

Three models, chosen by a scenario's ``links.model``:

* ``perfect`` — every message arrives at once (the fleet as it always was; no random draw);
* ``radio`` — log-distance path loss plus a loss per wall crossed: received power
  ``P = tx_power_dbm - loss_at_1m_db - 10 n log10(d / 1 m) - walls x wall_loss_db`` (d clamped
  to >= 1 m), margin ``m = P - sensitivity_dbm``;
* ``acoustic`` — transmission loss ``TL = 10 k log10(d / 1 m) + a(f) d / 1000`` (spreading
  factor k, Thorp's absorption a(f) in dB/km), margin ``m = source_level_db - TL -
  noise_level_db - snr_threshold_db``; delay ``d / sound_speed_mps``; the message occupies one
  shared half-duplex channel for ``8 x size / bitrate_bps`` seconds (one talker at a time: a
  message waits until the channel is free); a message longer than ``frame_bytes`` is refused.

Delivery probability of a hop with mean margin m: ``Phi(m / fade_db)`` (log-normal shadowing:
the received level is the mean plus a normal fade of standard deviation ``fade_db``; a step at
m = 0 when ``fade_db`` is 0). Randomness: a radio or acoustic hop draws exactly one uniform from
the caller's Generator, delivered or not, so the same seed gives the same fates; ``perfect``
draws nothing. The geometry (distances, walls crossed) comes from the caller: world/links.py
counts walls with pymunk; this module imports numpy and the standard library only.
"""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field

import numpy as np

from validation import Found, Flaw, Flaws, did_you_mean

MODELS = ("perfect", "radio", "acoustic")


@dataclass(frozen=True)
class Param:
    """One link parameter: default, inclusive range, unit and meaning (the docs' table)."""

    name: str
    default: float
    lo: float
    hi: float
    unit: str
    meaning: str
    integer: bool = False


RADIO_PARAMS = (
    Param("tx_power_dbm", 20.0, -30.0, 40.0, "dBm", "transmit power"),
    Param("loss_at_1m_db", 40.0, 0.0, 120.0, "dB", "path loss at 1 m (40 dB: free space at 2.4 GHz)"),
    Param("path_loss_exponent", 3.0, 1.0, 6.0, "", "log-distance exponent n (2 free space, 1.6-3.5 tunnels)"),
    Param("wall_loss_db", 12.0, 0.0, 60.0, "dB", "loss per wall crossed (concrete: 10-15 dB at 2.4 GHz)"),
    Param("sensitivity_dbm", -90.0, -130.0, -30.0, "dBm", "receiver sensitivity: margin 0 here"),
    Param("fade_db", 4.0, 0.0, 20.0, "dB", "standard deviation of the log-normal shadowing"),
    Param("latency_s", 0.005, 0.0, 10.0, "s", "delay of a delivered message per hop"),
)
ACOUSTIC_PARAMS = (
    Param("source_level_db", 170.0, 100.0, 230.0, "dB re 1 uPa at 1 m", "modem source level"),
    Param("frequency_khz", 25.0, 0.1, 200.0, "kHz", "carrier frequency (Thorp absorption)"),
    Param("spreading", 1.5, 1.0, 2.0, "", "spreading factor k (1 cylindrical, 1.5 practical, 2 spherical)"),
    Param("noise_level_db", 85.0, 0.0, 200.0, "dB re 1 uPa", "ambient noise in the modem's band"),
    Param("snr_threshold_db", 10.0, -20.0, 60.0, "dB", "SNR the modem needs: margin 0 here"),
    Param("fade_db", 3.0, 0.0, 20.0, "dB", "standard deviation of the log-normal fading"),
    Param("sound_speed_mps", 1500.0, 1300.0, 1700.0, "m/s", "speed of sound (sea water ~1,500)"),
    Param("bitrate_bps", 1000.0, 1.0, 1e6, "bit/s", "modem bit rate: a message occupies 8 x size / rate s"),
    Param("frame_bytes", 256, 1, 65535, "bytes", "largest frame the modem sends", integer=True),
)
RELAY_PARAMS = (
    Param("drop_margin_db", 10.0, 0.0, 60.0, "dB", "drop a relay when the margin to the last node is below this"),
    Param("step_m", 1.0, 0.1, 100.0, "m", "a carrier checks its link every step_m along its path"),
)
PARAMS = {"perfect": (), "radio": RADIO_PARAMS, "acoustic": ACOUSTIC_PARAMS}


@dataclass(frozen=True)
class RelaySpec:
    """Relay nodes: ``counts`` per carrier id (carriers not named carry none); the dropping rule's
    ``drop_margin_db`` and ``step_m``."""

    counts: tuple[tuple[str, int], ...] = ()
    drop_margin_db: float = RELAY_PARAMS[0].default
    step_m: float = RELAY_PARAMS[1].default

    def count(self, cid: str) -> int:
        return dict(self.counts).get(cid, 0)

    @property
    def total(self) -> int:
        return sum(n for _, n in self.counts)


@dataclass(frozen=True)
class LinkSpec:
    """A scenario's ``links``: the model, its parameters as (name, value) pairs (every parameter
    of the model, defaults filled in), the coordinator's base position (m; None: the first
    carrier's first waypoint) and the relays."""

    model: str = "perfect"
    params: tuple[tuple[str, float], ...] = ()
    base: tuple[float, float] | None = None
    relays: RelaySpec = field(default_factory=RelaySpec)

    def __getattr__(self, name: str) -> float:
        for key, value in self.__dict__.get("params", ()):
            if key == name:
                return value
        raise AttributeError(name)

    @classmethod
    def of(cls, model: str, **params: float) -> "LinkSpec":
        """The spec of ``model`` with ``params`` over the defaults (for code and tests)."""
        known = {p.name: p.default for p in PARAMS[model]}
        unknown = set(params) - set(known)
        if unknown:
            raise TypeError(f"unknown {model} parameter(s) {sorted(unknown)}")
        known.update(params)
        return cls(model=model, params=tuple(known.items()))


# --------------------------------------------------------------------------- checking

_LINK_KEYS = ("model", "base", "relays")
_RELAY_KEYS = ("count", "carriers", *(p.name for p in RELAY_PARAMS))


def _number(pb: Flaws, p: Param, value, path: str) -> float | None:
    ok = (not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
          and p.lo <= value <= p.hi and (not p.integer or float(value).is_integer()))
    if not ok:
        kind = "an integer" if p.integer else "a number"
        pb.add(path, f"{kind} from {p.lo:g} to {p.hi:g} ({p.unit or 'no unit'}: {p.meaning})", value)
        return None
    return int(value) if p.integer else float(value)


def check_links(node, carrier_ids: tuple[str, ...] | None,
                bounds: tuple[float, float, float, float] | None = None) -> tuple[LinkSpec | None, list[Flaw]]:
    """A scenario's ``links`` value (a model name or a mapping): the spec, or None and the
    problems with their field paths (``links.frame_bytes``, ``links.relays.carriers.c9`` ...).
    ``carrier_ids``: the scenario's carriers, ``bounds`` its map's (xmin, ymin, xmax, ymax) in m
    (None when they have problems of their own)."""
    pb = Flaws()
    if node is None:
        return LinkSpec(), []
    if isinstance(node, str):
        node = {"model": node}
    if not isinstance(node, dict):
        pb.add("links", f"a model name ({', '.join(MODELS)}) or a mapping {{model: ..., parameters}}", node)
        return None, list(pb)
    model = node.get("model", "perfect")
    if model not in MODELS:
        pb.add("links.model", f"one of {', '.join(MODELS)}{did_you_mean(model, MODELS)}", model)
        return None, list(pb)
    params = PARAMS[model]
    pb.unknown_keys(node, "links", (*_LINK_KEYS, *(p.name for p in params)))
    values = {}
    for p in params:
        v = _number(pb, p, node.get(p.name, p.default), f"links.{p.name}")
        if v is not None:
            values[p.name] = v
    base = None
    if "base" in node:
        b = node["base"]
        if (not isinstance(b, (list, tuple)) or len(b) != 2
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for v in b)):
            pb.add("links.base", "a point [x, y] (m): the coordinator's antenna or modem", b)
        elif bounds is not None and not (bounds[0] <= b[0] <= bounds[2] and bounds[1] <= b[1] <= bounds[3]):
            pb.add("links.base", f"a point inside map.bounds {list(bounds)}", b)
        else:
            base = (float(b[0]), float(b[1]))
    relays = RelaySpec()
    if "relays" in node:
        if model != "radio":
            pb.add("links.relays", "relays only with links.model radio (they are nodes of the radio model)",
                   Found(f"links.model {model}"))
        else:
            relays = _check_relays(pb, node["relays"], carrier_ids)
    if pb:
        return None, list(pb)
    return LinkSpec(model=model, params=tuple(values.items()), base=base, relays=relays), []


def _check_relays(pb: Flaws, node, carrier_ids: tuple[str, ...] | None) -> RelaySpec:
    """``links.relays``: ``count`` (every carrier) and/or ``carriers: {id: count}``, and the rule's
    parameters."""
    if not isinstance(node, dict):
        pb.add("links.relays", "a mapping {count: N} or {carriers: {id: N}} (relays per carrier)", node)
        return RelaySpec()
    pb.unknown_keys(node, "links.relays", _RELAY_KEYS)
    every = _number(pb, Param("count", 0, 0, 1000, "relays", "relays every carrier carries", True),
                    node.get("count", 0), "links.relays.count")
    named = node.get("carriers", {})
    counts = dict.fromkeys(carrier_ids or (), int(every or 0))
    if not isinstance(named, dict):
        pb.add("links.relays.carriers", "a mapping of carrier ids to relay counts", named)
    else:
        for cid, n in named.items():
            path = f"links.relays.carriers.{cid}"
            if carrier_ids is not None and str(cid) not in carrier_ids:
                pb.add(path, f"a carrier id ({', '.join(carrier_ids)})", Found(f"unknown carrier '{cid}'"))
                continue
            v = _number(pb, Param("count", 0, 0, 1000, "relays", "relays this carrier carries", True), n, path)
            if v is not None:
                counts[str(cid)] = int(v)
    rule = {p.name: _number(pb, p, node.get(p.name, p.default), f"links.relays.{p.name}") for p in RELAY_PARAMS}
    if any(v is None for v in rule.values()):
        return RelaySpec()
    return RelaySpec(counts=tuple((c, n) for c, n in counts.items() if n > 0), **rule)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- the channel

def thorp_db_per_km(f_khz: float) -> float:
    """Thorp's absorption of sea water (dB/km) at ``f_khz`` kHz (Thorp 1967, as in Stojanovic
    2007, "On the relationship between capacity and distance in an underwater acoustic
    communication channel")."""
    f2 = f_khz * f_khz
    return 0.11 * f2 / (1 + f2) + 44 * f2 / (4100 + f2) + 2.75e-4 * f2 + 0.003


def margin_db(spec: LinkSpec, distance: float, walls: int = 0) -> float:
    """Mean margin (dB) of one hop of ``distance`` m through ``walls`` walls: above 0 the hop is
    more likely delivered than not; +inf for ``perfect``."""
    d = max(float(distance), 1.0)
    if spec.model == "radio":
        received = (spec.tx_power_dbm - spec.loss_at_1m_db - 10 * spec.path_loss_exponent * math.log10(d)
                    - walls * spec.wall_loss_db)
        return received - spec.sensitivity_dbm
    if spec.model == "acoustic":
        loss = 10 * spec.spreading * math.log10(d) + thorp_db_per_km(spec.frequency_khz) * d / 1000
        return spec.source_level_db - loss - spec.noise_level_db - spec.snr_threshold_db
    return math.inf


def probability(spec: LinkSpec, margin: float) -> float:
    """Delivery probability of a hop with mean margin ``margin`` dB: Phi(margin / fade_db)."""
    if spec.model == "perfect" or margin == math.inf:
        return 1.0
    if spec.fade_db == 0:
        return 1.0 if margin >= 0 else 0.0
    return 0.5 * math.erfc(-margin / (spec.fade_db * math.sqrt(2)))


def open_range_m(spec: LinkSpec) -> float:
    """Distance (m) at which the mean margin reaches 0 with no wall (bisection; inf for
    ``perfect``): the model's nominal range."""
    if spec.model == "perfect":
        return math.inf
    lo, hi = 1.0, 1e7
    if margin_db(spec, lo) < 0:
        return 0.0
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if margin_db(spec, mid) >= 0 else (lo, mid)
    return lo


@dataclass(frozen=True)
class Channel:
    """The shared half-duplex acoustic channel: busy until ``free_at`` (s). A value: a
    transmission returns the channel after it."""

    free_at: float = -math.inf


@dataclass(frozen=True)
class Delivery:
    """The fate of one message.

    Attributes:
        delivered: whether it arrives.
        time: when it arrives (s, mission time); when lost, when it would have.
        probability: its delivery probability (the product over its hops).
        start: when its transmission began (s; later than the send time when it waited for the
            acoustic channel).
        channel: the acoustic channel after it (None for the other models).
    """

    delivered: bool
    time: float
    probability: float
    start: float
    channel: Channel | None = None


def airtime_s(spec: LinkSpec, size: int) -> float:
    """Seconds an acoustic message of ``size`` bytes occupies the channel (0 for other models)."""
    return 8.0 * size / spec.bitrate_bps if spec.model == "acoustic" else 0.0


def transmit(spec: LinkSpec, hops, size: int, send_time: float, rng: np.random.Generator,
             channel: Channel | None = None) -> Delivery:
    """One message over ``hops``, a sequence of (distance m, walls crossed) from sender to
    receiver (relays in between; one hop for a direct link), of ``size`` bytes, sent at
    ``send_time`` s. Draws one uniform per hop (none for ``perfect``).

    Acoustic: one hop; the message waits for ``channel`` (a fresh one when None), occupies it
    for :func:`airtime_s`, and arrives ``distance / sound_speed_mps`` after its last bit.

    Raises:
        ValueError: an acoustic message longer than ``frame_bytes`` (a scenario check refuses
            such a fleet, docs/scenario.md), or several acoustic hops.
    """
    hops = tuple(hops)
    if spec.model == "perfect":
        return Delivery(True, float(send_time), 1.0, float(send_time))
    if spec.model == "acoustic" and len(hops) != 1:
        raise ValueError(f"acoustic links have no relays: expected one hop, found {len(hops)}")
    if spec.model == "acoustic" and size > spec.frame_bytes:
        raise ValueError(f"a {size}-byte message does not fit links.frame_bytes = {spec.frame_bytes}")
    draws = rng.random(len(hops))
    ps = [probability(spec, margin_db(spec, d, w)) for d, w in hops]
    ok = bool(all(u < p for u, p in zip(draws, ps)))
    total = math.prod(ps)
    if spec.model == "radio":
        return Delivery(ok, float(send_time) + len(hops) * spec.latency_s, total, float(send_time))
    start = max(float(send_time), (channel or Channel()).free_at)
    end = start + airtime_s(spec, size)
    return Delivery(ok, end + hops[0][0] / spec.sound_speed_mps, total, start, Channel(end))


# --------------------------------------------------------------------------- connectivity

def hop_probabilities(spec: LinkSpec, distances: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """float ``[K, K]`` delivery probability of every direct hop between K nodes, from their
    distances (m) and walls crossed ``[K, K]``; 1 on the diagonal."""
    k = len(distances)
    out = np.ones((k, k))
    for i in range(k):
        for j in range(i + 1, k):
            out[i, j] = out[j, i] = probability(spec, margin_db(spec, float(distances[i, j]), int(walls[i, j])))
    return out


def best_path(prob: np.ndarray, src: int, dst: int) -> tuple[tuple[int, ...], float]:
    """The path of highest delivery probability (the product of its hops') from node ``src`` to
    ``dst`` in the graph of hop probabilities ``prob[K, K]`` (Dijkstra on -log p; ties go to the
    lower node index). Returns (nodes from src to dst, probability); ((), 0.0) when no path
    has a probability above 0."""
    k = len(prob)
    cost = [math.inf] * k
    prev = [-1] * k
    cost[src] = 0.0
    heap = [(0.0, src)]
    while heap:
        c, i = heapq.heappop(heap)
        if c > cost[i]:
            continue
        if i == dst:
            break
        for j in range(k):
            p = float(prob[i, j])
            if j == i or p <= 0.0:
                continue
            nc = c - math.log(p)
            if nc < cost[j] - 1e-12:
                cost[j], prev[j] = nc, i
                heapq.heappush(heap, (nc, j))
    if cost[dst] == math.inf:
        return (), 0.0
    path = [dst]
    while path[-1] != src:
        path.append(prev[path[-1]])
    return tuple(reversed(path)), math.exp(-cost[dst])
