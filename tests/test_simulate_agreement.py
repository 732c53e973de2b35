"""Simulation and the real fleet agree (issue 33, item 6; tools/sim_agreement.py): for each fault
kind of the real-process table (docs/fleet.md, "Faults", from docs/results/faults/faults.json),
the mean reward the simulator keeps over the same world seeds, the fault at the same stage,
lies within the real table's spread (min–max over its seeds)."""
from __future__ import annotations

import pytest

from tools.sim_agreement import KINDS, agreement

#: Fault kinds whose simulated mean lies outside the real spread (docs/fleet.md, "Deterministic
#: simulation", "Agreement with the real fleet"); this set may only shrink: a new one fails the
#: test, and so does a listed one that agrees. coordinator-cut-off: 87.0 % simulated against
#: 98.0 % (90.8–109.2) real, cause not found yet. The others agree narrowly (the simulator is
#: deterministic: the same seeds give the same figures): coordinator-killed 86.3 % against
#: 84.8–100.8, lossy-links 95.2 % against 94.8–100.0; with 2 missions a seed both fall outside.
KNOWN_APART = {"coordinator-cut-off"}


@pytest.mark.slow
def test_the_simulated_reward_kept_lies_within_the_real_spread():
    rows = agreement(missions=3)
    assert [row["fault"] for row in rows] == list(KINDS)
    apart = {row["fault"] for row in rows if not row["sim_mean_in_real_spread"]}
    assert apart == KNOWN_APART, {row["fault"]: (row["sim_mean"], min(row["real"]), max(row["real"])) for row in rows}
    assert all(len(row["sim"]) == 3 * len(row["real"]) for row in rows)  # three missions per world seed of the table
