"""A current field: the water's velocity over the map (m/s), a smooth function of position.

Model (docs/scenario.md, "current"): a uniform drift plus a sum of vortices. A vortex with
centre c, radius R and peak speed s turns the water around c (counter-clockwise for s > 0) at

    v(r) = s (r / R) exp((1 - r² / R²) / 2),   r = |p - c|,

which is 0 at the centre, peaks at s when r = R, and decays like a Gaussian beyond: smooth
everywhere and divergence-free. world/sim.py adds the current at a carrier's position to the
carrier's commanded velocity at every physics step (the command is relative to the water); the
tracking controller then works against it. A scenario without ``current`` has none, and its
physics is unchanged bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from validation import Flaw, Flaws

#: Largest current speed a file may give (m/s): a drift or a vortex's peak speed.
MAX_CURRENT_SPEED = 10.0
MAX_RADIUS = 1e6  # m


@dataclass(frozen=True)
class Vortex:
    """A vortex: ``center`` (m), ``radius`` R where its speed peaks (m), ``speed`` s at R (m/s;
    > 0 counter-clockwise)."""

    center: tuple[float, float]
    radius: float
    speed: float


@dataclass(frozen=True)
class CurrentSpec:
    """The current field: a uniform ``drift`` (u, v) in m/s plus ``vortices``."""

    drift: tuple[float, float] = (0.0, 0.0)
    vortices: tuple[Vortex, ...] = ()

    def at(self, x: float, y: float) -> tuple[float, float]:
        """The water's velocity (m/s) at (x, y) (m)."""
        u, v = self.drift
        for w in self.vortices:
            dx, dy = x - w.center[0], y - w.center[1]
            q = (dx * dx + dy * dy) / (w.radius * w.radius)
            k = w.speed / w.radius * math.exp((1.0 - q) / 2.0)  # v(r) / r
            u -= k * dy
            v += k * dx
        return u, v


def _speed(pb: Flaws, value, path: str) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not abs(value) <= MAX_CURRENT_SPEED:
        pb.add(path, f"a speed from -{MAX_CURRENT_SPEED:g} to {MAX_CURRENT_SPEED:g} m/s", value)
        return None
    return float(value)


def _pair(pb: Flaws, value, path: str, what: str, limit: float) -> tuple[float, float] | None:
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= limit for v in value)):
        pb.add(path, what, value)
        return None
    return (float(value[0]), float(value[1]))


def check_current(node) -> tuple[CurrentSpec | None, list[Flaw]]:
    """A scenario's ``current`` mapping ``{drift: [u, v], vortices: [{center, radius, speed}]}``:
    the spec, or None and the problems (``current.vortices[1].radius`` ...)."""
    pb = Flaws()
    if not isinstance(node, dict):
        pb.add("current", "a mapping {drift: [u, v], vortices: [{center: [x, y], radius: R, speed: s}]}", node)
        return None, list(pb)
    pb.unknown_keys(node, "current", ("drift", "vortices"))
    drift = _pair(pb, node.get("drift", [0.0, 0.0]), "current.drift",
                  f"[u, v], two speeds within +-{MAX_CURRENT_SPEED:g} m/s", MAX_CURRENT_SPEED)
    raw = node.get("vortices", [])
    vortices = []
    if not isinstance(raw, list):
        pb.add("current.vortices", "a list of vortices {center: [x, y], radius: R, speed: s}", raw)
        raw = []
    for i, w in enumerate(raw):
        path = f"current.vortices[{i}]"
        if not isinstance(w, dict):
            pb.add(path, "a mapping {center: [x, y], radius: R, speed: s}", w)
            continue
        pb.unknown_keys(w, path, ("center", "radius", "speed"))
        pb.missing(w, path, ("center", "radius", "speed"))
        c = _pair(pb, w["center"], f"{path}.center", "a point [x, y] (m)", MAX_RADIUS) if "center" in w else None
        r = w.get("radius")
        if "radius" in w and (isinstance(r, bool) or not isinstance(r, (int, float)) or not 0 < r <= MAX_RADIUS):
            pb.add(f"{path}.radius", f"a number > 0 and at most {MAX_RADIUS:g} (m)", r)
            r = None
        s = _speed(pb, w["speed"], f"{path}.speed") if "speed" in w else None
        if c is not None and r is not None and s is not None:
            vortices.append(Vortex(c, float(r), s))
    if pb or drift is None:
        return None, list(pb)
    return CurrentSpec(drift=drift, vortices=tuple(vortices)), []
