"""Shared test fixtures and the list of online planners that generic tests run over."""
from __future__ import annotations

import numpy as np
import pytest

#: Online planners every generic planner test (feasibility, causality, determinism, the
#: clairvoyant bound) runs over: (name for make_planner, options). Small budgets keep tests fast.
ONLINE_PLANNERS = [
    ("random", {}),
    ("ssap", {}),
    ("mcts-random", {"iterations": 40}),
    ("mcts-ssap", {"iterations": 40}),
    ("closed-loop", {"iterations": 40}),
    ("dec-mcts", {"iterations": 40}),
    ("dec-closed-loop", {"iterations": 40}),
]


def pytest_generate_tests(metafunc):
    if "planner_spec" in metafunc.fixturenames:
        metafunc.parametrize("planner_spec", ONLINE_PLANNERS, ids=[name for name, _ in ONLINE_PLANNERS])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
