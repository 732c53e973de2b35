"""Planners that see the links (issue 36, items 4 and 6): the communication model derived from a
predicted connectivity matrix (planner/comms.py LinkComms, contact), the hybrid fallback of
run_comms, and a carrier cut off from a coordinated fleet earning at least what SSAP alone would.
"""
from __future__ import annotations

import numpy as np
import pytest

from planner import ssap
from planner.comms import NEVER, CommsSpec, LinkComms, contact, realise
from planner.decentralised import run_comms
from planner.instance import random_instance
from planner.problem import evaluate
from planner.registry import make_planner


def _cut(R: int, N: int, r: int, start: int, stop: int) -> np.ndarray:
    """Connectivity ``[N, R + 1, R + 1]`` (0 the base): everyone hears everyone, except carrier r
    from stage ``start`` to ``stop - 1``."""
    p = np.ones((N, R + 1, R + 1))
    p[start:stop, 1 + r, :] = 0.0
    p[start:stop, :, 1 + r] = 0.0
    return p


def test_link_comms_checks_its_arrays():
    for bad in (np.ones((3, 3)), np.full((2, 3, 3), 1.5), np.full((2, 3, 3), -0.1), np.full((2, 3, 3), np.inf)):
        with pytest.raises(ValueError, match="link probabilities"):
            LinkComms(bad)
    with pytest.raises(ValueError, match="link delays"):
        LinkComms(np.ones((2, 3, 3)), delay=np.full((2, 3, 3), 0.5))
    with pytest.raises(ValueError, match=r"expected shape \[4, 3, 3\]"):
        LinkComms(np.ones((2, 3, 3))).check(2, 4)
    assert LinkComms(np.ones((2, 3, 3))).perfect and not LinkComms(_cut(2, 2, 0, 0, 1)).perfect


def test_deliveries_follow_the_predicted_connectivity():
    R, N = 3, 8
    p = _cut(R, N, 1, 2, 5)
    p[:, 0, 3] = p[:, 3, 0] = 0.5            # the coordinator and carrier 2: half the messages
    delay = np.zeros(p.shape, dtype=np.int64)
    delay[:, 1, 3] = 2                        # carrier 0 to carrier 2: two stages late
    dl = realise(LinkComms(p, delay), R, N, seed=7)
    again = realise(LinkComms(p, delay), R, N, seed=7)
    assert (dl.observation == again.observation).all() and (dl.decision == again.decision).all()
    cut = np.arange(N)[2:5]
    assert (dl.observation[1, [0, 2, 3]][:, cut] == NEVER).all()      # carrier 1 heard by nobody
    assert (dl.observation[[0, 2]][:, 1][:, cut] == NEVER).all()      # and hears nobody
    assert (dl.decision[1, cut] == NEVER).all() and (dl.decision[1, :2] == np.arange(2)).all()
    assert (dl.observation[1, 1] == np.arange(N)).all()               # a carrier hears itself
    assert (dl.observation[0, 2] == np.arange(N) + 2).all()           # late by its delay
    half = dl.decision[2] < NEVER
    assert 0 < half.sum() < N


def test_contact_is_the_prediction_of_either_model():
    R, N = 3, 5
    p = _cut(R, N, 0, 1, 3)
    p[4, 0, :] = np.nan                       # NaN: not in the mission (0)
    c = contact(LinkComms(p), R, N)
    assert c.shape == (N, R + 1, R + 1) and (c[:, np.arange(R + 1), np.arange(R + 1)] == 1).all()
    assert (c[1:3, 1, [0, 2, 3]] == 0).all() and (c[0] == 1).all() and (c[4, 0, 1:] == 0).all()
    g = contact(CommsSpec(loss=0.25, groups=((0, 1), (2,))), R, N)
    assert g[0, 0, 1] == g[0, 1, 2] == 0.75 and g[0, 0, 3] == g[0, 3, 1] == 0.0
    assert (contact(CommsSpec(delay=1), R, N)[:, 0, 1] == 0).all()  # late is not in time


def test_groups_as_connectivity_give_the_same_deliveries():
    """The derived model is the old one where they coincide: groups as a 0/1 matrix."""
    R, N = 4, 6
    spec = CommsSpec(groups=((0, 1), (2, 3)))
    old = realise(spec, R, N, seed=11)
    new = realise(LinkComms(contact(spec, R, N)), R, N, seed=11)
    for a, b in ((old.observation, new.observation), (old.intent, new.intent), (old.decision, new.decision)):
        assert (a == b).all()


def test_without_a_fallback_the_hybrid_runner_is_unchanged():
    inst = random_instance(np.random.default_rng(3), 4, 3, 10, 20, 3.0)
    central = make_planner("closed-loop", iterations=100)
    links = LinkComms(_cut(4, 10, 0, 3, 10))
    a = run_comms(inst.problem, inst.observations, central, 5, links)
    onboard = make_planner("dec-closed-loop", iterations=100)
    b = run_comms(inst.problem, inst.observations, central, 5, links, fallback=onboard)
    assert (a.deployed[1:, :3] == b.deployed[1:, :3]).all()
    assert a.deployed[0, 3:].sum() <= b.deployed[0, 3:].sum()  # forced only, against deciding alone


@pytest.mark.parametrize("seed", range(3))
def test_a_carrier_cut_off_earns_at_least_what_ssap_alone_would(seed):
    """Over many seeded instances (not those the rule was looked for on: tools.faults' six_carriers
    seeds): a carrier cut off from a coordinated fleet for the rest of the mission decides each
    stage exactly as SSAP alone, so the mission earns at least the SSAP substitute's reward."""
    rng = np.random.default_rng(1000 + seed)
    central = make_planner("closed-loop", iterations=200)
    onboard = make_planner("dec-closed-loop", iterations=200)
    for _ in range(12):
        R, N = int(rng.integers(3, 6)), int(rng.integers(6, 12))
        inst = random_instance(rng, R, 3, N, int(rng.integers(5, 25)), 3.0)
        r, start = int(rng.integers(R)), int(rng.integers(1, N - 2))
        mission_seed = int(rng.integers(2**31))
        result = run_comms(inst.problem, inst.observations, central, mission_seed, LinkComms(_cut(R, N, r, start, N)),
                           fallback=onboard)
        x = np.where(inst.problem.valid, inst.observations, np.nan)
        substitute = ssap.alone(inst.problem, x, result.deployed, r, start)
        assert (substitute == result.deployed).all()
        assert result.reward >= evaluate(inst.problem, substitute, x)[0] - 1e-9


def test_a_carrier_cut_off_from_a_decentralised_fleet_still_predicts_its_peers():
    """Without a coordinator the rule does not apply: dec-closed-loop hearing nobody predicts
    its peers by their thresholds (and so differs from SSAP somewhere)."""
    rng = np.random.default_rng(5)
    dec = make_planner("dec-closed-loop", iterations=200)
    differs = 0
    for _ in range(6):
        inst = random_instance(rng, 4, 3, 10, 20, 3.0)
        alone = run_comms(inst.problem, inst.observations, dec, 1, CommsSpec(loss=1.0))
        plain = run_comms(inst.problem, inst.observations, make_planner("ssap"), 1, CommsSpec(loss=1.0))
        differs += int((alone.deployed != plain.deployed).any())
    assert differs > 0


def test_predicted_awareness_follows_the_contact_matrix():
    from planner.decentralised import LocalView, predicted_aware

    inst = random_instance(np.random.default_rng(2), 3, 2, 6, 5, 3.0)
    R, N = 3, 6
    empty = np.full((R, N), np.nan)
    view = LocalView(inst.problem, 0, 0, 0, empty, np.zeros((R, N), bool), np.zeros(R, np.int64),
                     np.zeros(R, np.int64), (None,) * R)
    comp = np.array([0, 2])
    assert predicted_aware(view, comp).all()                       # no prediction: everyone hears
    c = contact(LinkComms(_cut(R, N, 2, 2, 4)), R, N)
    from dataclasses import replace

    assert predicted_aware(replace(view, contact=c), comp).all()        # no coordinator: peers predicted
    aware = predicted_aware(replace(view, contact=c, coordinated=True), comp)
    assert aware[0].all() and not aware[1, 2:4].any()                    # 0 still hears the coordinator
    # Cut off from carrier 0 only, carrier 2 still hears the coordinator: aware when coordinated.
    p = np.ones((N, R + 1, R + 1))
    p[:, 1, 3] = p[:, 3, 1] = 0.0
    lone = replace(view, contact=contact(LinkComms(p), R, N))
    assert predicted_aware(replace(lone, coordinated=True), comp)[1].all()
    p[:, 0, 3] = 0.0
    alone = replace(view, contact=contact(LinkComms(p), R, N), coordinated=True)
    assert not predicted_aware(alone, comp)[1].any() and predicted_aware(alone, comp)[0].all()


def test_the_world_predicts_the_links_of_a_scenario():
    import world
    from world.linkplan import link_comms, summary
    from world.links import LinkModel
    from world.paths import REPO_ROOT

    marine = world.load_scenario(REPO_ROOT / "scenarios" / "marine_survey.yaml")
    comms = link_comms(marine)
    R, N = marine.n_carriers, marine.stages
    comms.check(R, N)
    model = LinkModel(marine)
    j = 5
    t = float(marine.stage_time(j))
    a, b = marine.carriers[0].position_at(t), marine.carriers[2].position_at(t)
    assert comms.probability[j, 1, 3] == pytest.approx(model.probability(a, b))    # the direct hop
    assert comms.probability[j, 0, 1] == pytest.approx(model.probability(model.base, a))
    valid = marine.valid()
    assert np.isnan(comms.probability[:, 1:, 0][~valid.T]).all()
    figures = summary(comms)
    assert 0.5 < figures["least"] <= figures["mean"] < 1.0
    # Slower modems, longer frames: the stage's messages no longer cross within a stage.
    import dataclasses

    slow = dataclasses.replace(marine, links=dataclasses.replace(
        marine.links, params=tuple((k, 50.0 if k == "bitrate_bps" else 4096 if k == "frame_bytes" else v)
                                   for k, v in marine.links.params)))
    late = link_comms(slow)
    assert late.delay is not None and late.delay.max() >= 1
    six = world.load_scenario(REPO_ROOT / "scenarios" / "six_carriers.yaml")
    assert link_comms(six).perfect


def test_the_targets_tool_prints_the_cut_off_table(capsys):
    from tools.links_targets import main

    assert main(["cut-off", "--seeds", "2", "--iterations", "100"]) == 0
    out = capsys.readouterr().out
    assert "| 2 |" in out and "below SSAP alone on 0 of 2 seeds" in out
    assert main(["loss", "--trials", "0"]) == 2
