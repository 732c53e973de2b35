"""Planning under a communication model (planner/comms.py, planner/decentralised.py,
planner/decmcts.py): the deliveries, identity with the central loop when links are perfect
(directly and against tests/golden), feasibility of every planner under every communication
model, causality, determinism, the reductions to SSAP, the solve flags and the comms experiment.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import in_process
from planner.comms import NEVER, CommsSpec, parse_groups, realise
from planner.decentralised import LocalDecision, run_comms
from planner.decmcts import optimise_distribution
from planner.instance import random_instance
from planner.online import run_online
from planner.registry import make_planner

HERE = Path(__file__).resolve().parent
BUDGET = 150
ALL = ("random", "ssap", "mcts-ssap", "mcts-random", "closed-loop", "dec-mcts", "dec-closed-loop")
DECENTRALISED = ("dec-mcts", "dec-closed-loop")
MODELS = {
    "perfect": CommsSpec(),
    "loss-half": CommsSpec(loss=0.5),
    "loss-all": CommsSpec(loss=1.0),
    "delay-1": CommsSpec(loss=0.25, delay=1),
    "groups": CommsSpec(groups=((0, 1), (2,))),
}


def _planner(name, iterations=BUDGET):
    return make_planner(name, iterations=iterations)


def _instances(seed, count, **kw):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        carriers = kw.get("carriers", int(rng.integers(1, 5)))
        yield random_instance(rng, carriers=carriers, passengers=kw.get("passengers", rng.integers(0, 4, size=carriers).tolist()),
                              stages=kw.get("stages", int(rng.integers(1, 8))),
                              overlaps=kw.get("overlaps", int(rng.integers(0, 10))), mean=3.0,
                              invalid_fraction=kw.get("invalid_fraction", float(rng.choice([0.0, 0.2]))))


# ----------------------------------------------------------------------------- the model


def test_spec_validation_and_groups_syntax():
    assert parse_groups("0,1/2,3") == ((0, 1), (2, 3))
    assert parse_groups("2") == ((2,),)
    for bad in ("0,1/1", "a,b", "0,,1", "-1"):
        with pytest.raises(ValueError):
            parse_groups(bad)
    for kw in ({"loss": -0.1}, {"loss": 1.5}, {"delay": -1}, {"delay": 0.5}, {"groups": ((0,), (0,))}):
        with pytest.raises(ValueError):
            CommsSpec(**kw)
    with pytest.raises(ValueError, match="outside"):
        CommsSpec(groups=((0, 5),)).check(3)
    assert CommsSpec().perfect and not CommsSpec(loss=0.1).perfect and not CommsSpec(delay=1).perfect


def test_deliveries_are_seeded_and_follow_the_spec():
    R, N = 4, 6
    perfect = realise(CommsSpec(), R, N, seed=3)
    stages = np.arange(N)
    assert (perfect.observation == stages).all() and (perfect.decision == stages).all()
    assert (perfect.intent == stages + 1).all()
    lossy = realise(CommsSpec(loss=0.5), R, N, seed=3)
    again = realise(CommsSpec(loss=0.5), R, N, seed=3)
    assert (lossy.observation == again.observation).all() and (lossy.intent == again.intent).all()
    dropped = (lossy.observation[:, :R] == NEVER)
    assert 0.3 < dropped.mean() < 0.7
    assert not dropped[np.arange(R), np.arange(R)].any()  # a carrier hears itself
    silent = realise(CommsSpec(loss=1.0), R, N, seed=3)
    assert (silent.decision == NEVER).all() and (silent.observation[:, R] == NEVER).all()
    late = realise(CommsSpec(delay=2), R, N, seed=3)
    assert (late.observation[0, 1] == stages + 2).all() and (late.intent[0, 1] == stages + 3).all()
    split = realise(CommsSpec(groups=((0, 1), (2, 3))), R, N, seed=3)
    assert (split.observation[0, 2] == NEVER).all() and (split.observation[0, 1] == stages).all()
    assert (split.observation[2, R] == NEVER).all() and (split.observation[1, R] == stages).all()  # coordinator: group 1
    assert (split.decision[2] == NEVER).all() and (split.decision[0] == stages).all()


# ----------------------------------------------------------------------------- perfect links


@pytest.mark.parametrize("name", ["random", "ssap", "mcts-ssap", "closed-loop"])
def test_perfect_links_reproduce_run_online_exactly(name):
    planner = _planner(name)
    for k, (problem, x) in enumerate(_instances(11, 12)):
        a = run_online(problem, x, planner, seed=k)
        b = run_comms(problem, x, planner, seed=k, comms=CommsSpec())
        assert (a.deployed == b.deployed).all() and a.reward == b.reward and a.features == b.features


@pytest.mark.parametrize("case", ["paper-0", "paper-1", "paper-2"])
def test_perfect_links_reproduce_the_golden_outputs(case):
    sys.path.insert(0, str(HERE / "golden"))
    import record
    from planner.solve import solve_instance

    golden = json.loads((HERE / "golden" / "solve.json").read_text())
    changed = json.loads((HERE / "golden" / "solve_changed.json").read_text())  # tests/test_golden.py's CHANGED
    for name in record.PLANNERS:
        budget = record.ITERATIONS if name.startswith(("mcts", "closed")) else None
        out = solve_instance(HERE / "golden" / "instances" / f"{case}.json", make_planner(name, iterations=budget),
                             name, record.SEED, online_optimum=False, comms=CommsSpec(), upper_bound=False)
        out.pop("decision_ms")
        assert out.pop("comms") == {"loss": 0.0, "delay": 0, "groups": []}
        assert out == changed.get(case, {}).get(name, golden[case][name]), name


def test_dec_closed_loop_is_closed_loop_with_perfect_links():
    central, dec = _planner("closed-loop", 400), _planner("dec-closed-loop", 400)
    for k, (problem, x) in enumerate(_instances(12, 10, carriers=4, overlaps=15, stages=8)):
        a = run_online(problem, x, central, seed=k)
        b = run_comms(problem, x, dec, seed=k, comms=CommsSpec())
        assert (a.deployed == b.deployed).all()


# ----------------------------------------------------------------------------- every model


@pytest.mark.parametrize("model", list(MODELS), ids=list(MODELS))
def test_every_planner_is_feasible_under_every_model(model):
    comms = MODELS[model]
    for name in ALL:
        planner = _planner(name, 60)
        for k, (problem, x) in enumerate(_instances(13, 4, carriers=3)):
            result = run_comms(problem, x, planner, seed=k, comms=comms)  # raises on a broken rule
            valid = ~np.isnan(x)
            assert not (result.deployed & ~valid).any(), name
            # Forced deployments are the carriers' own rule: every passenger that can go, goes.
            assert result.deployed.sum(axis=1).tolist() == np.minimum(problem.passengers, valid.sum(axis=1)).tolist()


class _Spy:
    """Wraps a planner and records what each decision could see."""

    def __init__(self, inner):
        self.inner, self.seen = inner, []
        if hasattr(inner, "decide_local"):
            self.decide_local = self._local
        self.name = inner.name

    def decide(self, view, rng):
        self.seen.append(("coordinator", view))
        return self.inner.decide(view, rng)

    def _local(self, local, rng):
        self.seen.append(("carrier", local))
        return self.inner.decide_local(local, rng)


@pytest.mark.parametrize("name", ["closed-loop", "dec-closed-loop", "dec-mcts"])
def test_causality_no_decision_uses_an_undelivered_observation(name):
    comms = CommsSpec(loss=0.5, delay=1)
    for k, (problem, x) in enumerate(_instances(14, 4, carriers=3, stages=6, passengers=2, overlaps=8)):
        spy = _Spy(_planner(name, 60))
        result = run_comms(problem, x, spy, seed=k, comms=comms)
        dl = realise(comms, problem.n_carriers, problem.n_stages, k)
        R = problem.n_carriers
        xs = np.where(problem.valid, x, np.nan)
        for who, view in spy.seen:
            j = view.stage
            receiver = R if who == "coordinator" else view.carrier
            for b in range(R):
                for t in range(problem.n_stages):
                    # Messages from b sent at s >= t (they carry x[b, t]) that reached the receiver by j.
                    heard = b == receiver or (dl.observation[b, receiver, t:j + 1] <= j).any() or (
                        who == "carrier" and (dl.intent[b, receiver, t:j + 1] <= j).any())
                    value = view.observations[b, t]
                    if not heard:
                        assert np.isnan(value), (who, b, t, j)
                    elif not np.isnan(value):
                        assert value == xs[b, t]
            if who == "carrier":
                # Known deployments are the truth.
                known = np.arange(problem.n_stages)[None, :] < view.record[:, None]
                assert (view.deployed == (result.deployed & known)).all()


@pytest.mark.parametrize("name", DECENTRALISED + ("closed-loop",))
def test_deterministic_for_a_seed(name):
    planner = _planner(name, 200)
    for k, (problem, x) in enumerate(_instances(15, 3, carriers=4, overlaps=12, stages=8)):
        a = run_comms(problem, x, planner, seed=k, comms=CommsSpec(loss=0.5))
        b = run_comms(problem, x, _planner(name, 200), seed=k, comms=CommsSpec(loss=0.5))
        assert (a.deployed == b.deployed).all()


@pytest.mark.parametrize("name", DECENTRALISED)
def test_without_overlaps_and_perfect_links_they_are_ssap(name):
    ssap = _planner("ssap")
    for k, (problem, x) in enumerate(_instances(16, 10, overlaps=0)):
        a = run_online(problem, x, ssap, seed=k)
        b = run_comms(problem, x, _planner(name), seed=k, comms=CommsSpec())
        assert (a.deployed == b.deployed).all()


@pytest.mark.parametrize("name", DECENTRALISED + ("ssap",))
@pytest.mark.parametrize("loss", [0.0, 0.5, 1.0])
def test_one_carrier_is_ssap_at_any_loss(name, loss):
    ssap = _planner("ssap")
    for k, (problem, x) in enumerate(_instances(17, 8, carriers=1, overlaps=0)):
        a = run_online(problem, x, ssap, seed=k)
        b = run_comms(problem, x, _planner(name), seed=k, comms=CommsSpec(loss=loss, delay=int(loss > 0)))
        assert (a.deployed == b.deployed).all()


def test_centralised_fallback_without_messages_is_forced_only():
    for k, (problem, x) in enumerate(_instances(18, 5, carriers=3, passengers=2, stages=6)):
        result = run_comms(problem, x, _planner("closed-loop"), seed=k, comms=CommsSpec(loss=1.0))
        valid = ~np.isnan(x)
        for r in range(problem.n_carriers):
            stages = np.flatnonzero(valid[r])
            expected = stages[len(stages) - min(len(stages), int(problem.passengers[r])):]
            assert np.flatnonzero(result.deployed[r]).tolist() == expected.tolist()


def test_dec_closed_loop_without_messages_beats_ssap_on_conflicted_instances():
    # Paired, 16 paper-style instances with 20 overlaps: no message at all.
    ssap, dec = _planner("ssap"), _planner("dec-closed-loop", 400)
    diffs = []
    for k, (problem, x) in enumerate(_instances(19, 16, carriers=4, passengers=3, stages=10, overlaps=20,
                                                invalid_fraction=0.0)):
        diffs.append(run_comms(problem, x, dec, k, CommsSpec(loss=1.0)).reward
                     - run_comms(problem, x, ssap, k, CommsSpec(loss=1.0)).reward)
    diffs = np.asarray(diffs)
    assert diffs.mean() > 2 * diffs.std(ddof=1) / np.sqrt(len(diffs))


def test_intent_distribution_moves_to_the_better_sequences():
    q = optimise_distribution(np.array([1.0, 2.0, 0.5]))
    assert q.argmax() == 1 and abs(q.sum() - 1) < 1e-9 and (q > 0).all()


def test_decentralised_planners_run_centrally_with_full_information():
    from planner.problem import make_view, stage_rng

    problem, x = next(_instances(20, 1, carriers=3, overlaps=6, stages=6, passengers=2))
    for name in DECENTRALISED:
        a = run_online(problem, x, _planner(name), seed=1)  # run_online routes to run_comms
        b = run_comms(problem, x, _planner(name), seed=1)
        assert (a.deployed == b.deployed).all()
        # decide(view, rng) on the full view (a central caller) is every carrier's own decision
        # with full information: with perfect links, stage 0 has no intents yet, so it matches.
        view = make_view(problem, 0, x, np.zeros(problem.valid.shape, bool))
        assert (_planner(name).decide(view, stage_rng(1, 0)) == a.deployed[:, 0]).all()
    assert LocalDecision(True).intent is None


# ----------------------------------------------------------------------------- command line


def _solve(*args):
    from planner.cli import solve as cli

    done = in_process(cli.main, args)
    return done.returncode, done.stdout, done.stderr


def test_solve_message_flags(tmp_path):
    path = HERE / "golden" / "instances" / "paper-0.json"
    # The upper bound is computed within a wall-clock budget: present or not depending on the load.
    base = ["--planner", "ssap", "--no-online-optimum", "--no-clairvoyant", "--no-upper-bound"]
    code, plain, _ = _solve(str(path), *base)
    code0, zero, _ = _solve(str(path), *base, "--message-loss", "0", "--message-delay", "0")
    assert code == code0 == 0
    a, b = json.loads(plain), json.loads(zero)
    a.pop("decision_ms"), b.pop("decision_ms")
    assert a == b
    code, lossy, _ = _solve(str(path), "--planner", "closed-loop", "--iterations", "50", "--no-online-optimum",
                            "--no-clairvoyant", "--message-loss", "0.5", "--message-delay", "1", "--groups", "0,1/2,3")
    assert code == 0 and json.loads(lossy)["comms"] == {"loss": 0.5, "delay": 1, "groups": [[0, 1], [2, 3]]}
    for bad in (["--message-loss", "1.5"], ["--message-loss", "x"], ["--message-delay", "-1"], ["--groups", "0,0"],
                ["--groups", "0,9"]):
        code, _, err = _solve(str(path), *base, *bad)
        assert code == 2 and len(err.strip().splitlines()) == 1, (bad, err)


def test_comms_experiment_quick(tmp_path):
    from experiments import run

    code = run.main(["comms", "--quick", "--jobs", "1", "--no-progress", "--out", str(tmp_path),
                     "--losses", "0,1", "--trials", "2"])
    assert code == 0
    for name in ("comms_trials.csv", "comms_summary.csv", "comms.md", "comms-r4.png", "comms-r6.png"):
        assert (tmp_path / name).is_file()
    text = (tmp_path / "comms.md").read_text()
    assert "Dec-closed-loop" in text and "Dec-MCTS" in text


@pytest.mark.parametrize("name", DECENTRALISED)
def test_time_budget_per_carrier(name):
    planner = make_planner(name, plan_ms=3.0)
    for k, (problem, x) in enumerate(_instances(21, 3, carriers=3, overlaps=8, stages=6, passengers=2)):
        result = run_comms(problem, x, planner, seed=k, comms=CommsSpec(loss=0.5))
        valid = ~np.isnan(x)
        assert result.deployed.sum(axis=1).tolist() == np.minimum(problem.passengers, valid.sum(axis=1)).tolist()
