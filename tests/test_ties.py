"""Same decisions on every machine: thresholds are computed with correctly rounded sums, and the
threshold rule's ties (a value equal to a threshold in exact arithmetic) stay whatever the last
bits of either (planner.ssap.TIE, docs/planner.md "Ties and rounding").

The failure these guard against: the uniform prior on 0..6 has thresholds exactly 3; np.dot gave
E[X] = 2.9999999999999996 with OpenBLAS's AVX2 kernel and 3.0 with its AVX-512 one (fused
multiply-add), and the golden mcts-ssap solve of tests/golden/instances/prior-discrete_uniform.json
differed between two machines. Here the thresholds are moved by a few units in the last place, as
another CPU or library build would, and every decision must stay the same.
"""
from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from planner import priors, ssap
from planner.compiled import compile_problem
from planner.instance import load_instance
from planner.kernels import deploys as kernel_deploys
from planner.kernels import rank as kernel_rank
from planner.online import run_online
from planner.registry import make_planner

INSTANCE = Path(__file__).resolve().parent / "golden" / "instances" / "prior-discrete_uniform.json"
UNIFORM = {"kind": "discrete_uniform", "low": 0, "high": 6}


def _exact_uniform_table(n_max: int) -> dict:
    """DLR thresholds of the uniform prior on 0..6 in rational arithmetic: {(n, i): Fraction}
    for 1 <= i < n (the infinite ends are None)."""
    def clip(p, lo, hi):
        return min(max(p, lo) if lo is not None else p, hi) if hi is not None else (max(p, lo) if lo is not None else p)

    a = {}
    for n in range(1, n_max + 2):
        a[n, 0] = a[n, n] = None
        for i in range(1, n):
            a[n, i] = sum(clip(Fraction(v), a[n - 1, i - 1], a[n - 1, i]) for v in range(7)) / 7
    return a


def _nudged(table: np.ndarray, ulps: int) -> np.ndarray:
    """``table`` with every finite entry moved by ``ulps`` units in the last place."""
    out = np.array(table, dtype=np.float64)
    toward = np.inf if ulps > 0 else -np.inf
    for _ in range(abs(ulps)):
        finite = np.isfinite(out)
        out[finite] = np.nextafter(out[finite], toward)
    return out


def test_uniform_thresholds_are_the_exact_ones_correctly_rounded_at_their_ties():
    table = ssap.thresholds(priors.build_prior(UNIFORM), 8)
    exact = _exact_uniform_table(8)
    ties = sorted((n, i) for (n, i), v in exact.items() if v is not None and v.denominator == 1)
    assert ties == [(2, 1), (4, 2), (6, 3), (8, 4)]
    # E[X] by a correctly rounded sum: exactly 3 (np.dot gave 2.9999999999999996 on AVX2 CPUs).
    assert table[2, 1] == 3.0
    for (n, i), v in exact.items():
        if v is not None and 1 <= i < n:
            assert abs(table[n, i] - float(v)) <= 8 * np.spacing(float(v)), (n, i)


@pytest.mark.parametrize("ulps", [-4, -1, 0, 1, 4])
def test_a_tie_stays_whatever_the_last_bits(ulps):
    table = _nudged(ssap.thresholds(priors.build_prior(UNIFORM), 8), ulps)
    for n, d in [(2, 1), (4, 2), (6, 3), (8, 4)]:  # thresholds exactly 3 in exact arithmetic
        for x in (3.0, 6.0 / 2.0, 9.0 / 3.0):  # an observation and conflict-discounted ones
            assert not ssap.deploys(table, x, n, d)
            assert not kernel_deploys(table, x, n, d)
        assert ssap.deploys(table, 3.0 + 1e-6, n, d) and kernel_deploys(table, 3.0 + 1e-6, n, d)
        assert ssap.deploys(table, 4.0, n, d) and not ssap.deploys(table, 2.0, n, d)
        for x in (2.0, 3.0, 4.0):
            assert ssap.rank(table, x, n) == kernel_rank(table, x, n)
            # rank <= d iff the rule deploys (not forced here: n > d)
            assert (ssap.rank(table, x, n) <= d) == ssap.deploys(table, x, n, d)


def test_the_kernels_uniform_cut_agrees_with_the_rule_on_nudged_thresholds():
    """ucut (the sampler's CDF at each threshold's cut) is the same table for thresholds a few
    units in the last place apart, and decides like the rule on every support point."""
    (problem, _), _ = load_instance(INSTANCE)
    cp = compile_problem(problem)
    base = cp.ucut
    points = cp.sampler.points
    for ulps in (-4, -1, 1, 4):
        table = _nudged(cp.table, ulps)
        other = type(cp)(cp.n_carriers, cp.n_stages, cp.scale, cp.sampler, cp.conflict, cp.indptr, cp.nbr, cp.prior)
        other.__dict__["table"] = table  # the cached_property's slot: thresholds as another machine computed them
        assert np.array_equal(other.ucut, base), ulps
        for n in range(2, cp.n_stages + 1):
            for d in range(1, n):
                u_cut = base[n, n - d]
                for k, x in enumerate(points.tolist()):
                    u = cp.sampler.cdf[k - 1] if k else 0.0  # the smallest uniform drawing point k
                    assert (u >= u_cut) == ssap.deploys(table, x, n, d), (ulps, n, d, x)


def _solve_with_table(table: np.ndarray | None):
    (problem, x), _ = load_instance(INSTANCE)
    if table is not None:
        cp = compile_problem(problem)
        assert "table" not in cp.__dict__
        cp.__dict__["table"] = table  # as another CPU's arithmetic would have computed it
    planner = make_planner("mcts-ssap", iterations=1500)
    result = run_online(problem, x, planner, 7)
    return [np.flatnonzero(row).tolist() for row in result.deployed], result.reward


def test_mcts_ssap_decides_the_same_on_thresholds_a_few_ulps_apart():
    """The golden case that differed between machines: the whole online run is identical when
    every threshold is moved by a few units in the last place either way."""
    (problem, _), _ = load_instance(INSTANCE)
    table = np.array(ssap.thresholds(problem.prior, problem.n_stages))
    reference = _solve_with_table(None)
    golden = json.loads((INSTANCE.parents[1] / "solve_changed.json").read_text())
    pinned = golden["prior-discrete_uniform"]["mcts-ssap"]
    assert reference == (pinned["deployments"], pinned["reward"])
    for ulps in (-4, -1, 1, 4):
        assert _solve_with_table(_nudged(table, ulps)) == reference, ulps
