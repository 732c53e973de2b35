"""Shared test fixtures and the list of online planners that generic tests run over."""
from __future__ import annotations

import sys

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


#: pytest keeps the test modules it rewrites (for its assertion messages) only where bytecode may be
#: written: on a host that sets PYTHONDONTWRITEBYTECODE every worker of every run rewrote all of
#: them again (about 10 s of each worker's start on a 2-core host). Collection writes them beside
#: the tests (``tests/__pycache__``, as an unset variable would); the tests run with the host's
#: setting.
_DONT_WRITE_BYTECODE = sys.dont_write_bytecode


def pytest_collection(session):
    sys.dont_write_bytecode = False


def pytest_collection_finish(session):
    sys.dont_write_bytecode = _DONT_WRITE_BYTECODE
