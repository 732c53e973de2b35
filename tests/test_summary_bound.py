"""The run against its bound, as the console, summary.json and map.png state it: a percentage
only against the exact offline optimum, or against the information-relaxation bound on every
online planner when the offline search stopped at its node limit (the conflict-free bound left
then is loose, and a percentage of it makes every planner look broken)."""
from __future__ import annotations

import re

import numpy as np
import pytest

import world
from mission.summary import bound_text, clairvoyant_bound, online_upper_bound
from world.paths import REPO_ROOT


@pytest.fixture(scope="module")
def six():
    s = world.load_scenario(REPO_ROOT / "scenarios" / "six_carriers.yaml")
    problem = world.build_problem(s)
    x = world.observe_all(s, s.seed)
    return s, problem, x


def _percentages(text: str) -> list[str]:
    return re.findall(r"\d+%", text)


def test_the_exact_optimum_gets_a_percentage(six):
    s, problem, x = six
    bound = clairvoyant_bound(problem, x, 1.0)
    assert bound["exact"] and bound["percent"] == pytest.approx(100.0 / bound["reward"])
    text = bound_text({"clairvoyant": bound})
    assert text.startswith("clairvoyant optimum") and _percentages(text) == [f"{bound['percent']:.0f}%"]


def test_a_loose_bound_gets_none_and_says_why(six):
    s, problem, x = six
    loose = clairvoyant_bound(problem, x, 1.0, max_nodes=1)  # the search stops at once
    assert loose["exact"] is False and loose["percent"] is None and "conflict-free" in loose["loose"]
    assert loose["fraction"] == pytest.approx(1.0 / loose["reward"])  # kept, as before
    text = bound_text({"clairvoyant": loose})
    assert "loose" in text and _percentages(text) == [], text
    # with the information-relaxation bound, the percentage is against it
    upper = online_upper_bound(problem, s.seed, 1.0)
    assert upper["samples"] >= 20 and upper["expected_reward"] > 0
    assert upper["expected_reward"] < loose["reward"]  # tighter than clairvoyance that ignores conflicts
    both = bound_text({"clairvoyant": loose, "upper_bound": upper})
    assert _percentages(both) == [f"{upper['percent']:.0f}%"] and "information-relaxation" in both
    short = bound_text({"clairvoyant": loose, "upper_bound": upper}, short=True)
    assert len(short) < len(both) and _percentages(short) == _percentages(both)


def test_no_upper_bound_where_it_does_not_apply(six):
    s, problem, x = six
    import dataclasses

    typed = dataclasses.replace(problem, weights=np.ones((problem.n_carriers, int(problem.passengers.max()))))
    assert "error" in online_upper_bound(typed, s.seed, 1.0)
