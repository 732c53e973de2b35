"""The planners' communication model of a scenario, from its link model (issue 36, item 4): who
can hear whom at which stage, predicted from the stage positions before the mission.

The planner side (:class:`planner.comms.LinkComms`) takes the matrix as data; this module
computes it on the world:

* ``perfect``: every message at once (NaN for a carrier not in the mission at the stage);
* ``radio``: the best path's delivery probability between every two participants at each stage
  time, through the relays dropped by then and the carriers in between
  (:func:`world.relays.stage_connectivity`);
* ``acoustic``: the direct hop's (an acoustic message has no relays, planner/links.py), late by
  whole stages when the stage's messages cannot cross in one stage: at most every valid
  carrier's observation and the coordinator's decision, each a full frame, share the one
  half-duplex channel, and the last one travels ``distance / sound_speed_mps`` after its last
  bit — ``delay = floor((k + 1) x airtime(frame_bytes) + distance / sound_speed) / stage_interval)``
  with k the valid carriers (a bound: the fleet's messages are often shorter).
"""
from __future__ import annotations

import math

import numpy as np

from planner import links as ch
from planner.comms import LinkComms
from world.links import LinkModel
from world.relays import fleet_relays, stage_connectivity
from world.scenario import Scenario


def link_comms(scenario: Scenario, model: LinkModel | None = None) -> LinkComms:
    """The :class:`planner.comms.LinkComms` of ``scenario`` (index 0 the base, 1 + r carrier r)."""
    model = model or LinkModel(scenario)
    spec = model.spec
    if spec.model == "radio":
        return LinkComms(stage_connectivity(model, fleet_relays(model)))
    valid = scenario.valid()
    R, N = scenario.n_carriers, scenario.stages
    prob = np.full((N, R + 1, R + 1), np.nan)
    delay = np.zeros((N, R + 1, R + 1), dtype=np.int64)
    for j in range(N):
        t = float(scenario.stage_time(j))
        here = [r for r in range(R) if valid[r, j]]
        index = np.asarray([0] + [1 + r for r in here])
        nodes = np.vstack([np.asarray([model.base], dtype=float),
                           np.asarray([scenario.carriers[r].position_at(t) for r in here], dtype=float).reshape(-1, 2)])
        prob[j][np.ix_(index, index)] = model.graph(nodes)
        if spec.model == "acoustic":
            dist = np.hypot(nodes[:, None, 0] - nodes[None, :, 0], nodes[:, None, 1] - nodes[None, :, 1])
            busy = (len(here) + 1) * ch.airtime_s(spec, int(spec.frame_bytes))
            late = np.floor((busy + dist / spec.sound_speed_mps) / scenario.stage_interval).astype(np.int64)
            delay[j][np.ix_(index, index)] = late
    return LinkComms(prob, delay if delay.any() else None)


def summary(comms: LinkComms) -> dict:
    """Figures of a prediction for a report: the mean and least delivery probability between the
    base and the carriers over the stages they are in the mission, and the fraction of
    (stage, carrier) pairs predicted out of the base's reach (probability below 1/2)."""
    p = comms.probability[:, 0, 1:]
    inside = p[np.isfinite(p)]
    if inside.size == 0:
        return {"mean": math.nan, "least": math.nan, "out_of_reach": math.nan}
    return {"mean": float(inside.mean()), "least": float(inside.min()), "out_of_reach": float((inside < 0.5).mean())}
