"""Simulation and the real fleet agree (issue 33, item 6; tools/sim_agreement.py): for each fault
kind of the real-process table (docs/fleet.md, "Faults", from docs/results/faults/faults.json),
the mean reward the simulator keeps over the same world seeds, the fault at the same stage,
lies within the real table's spread (min–max over its seeds)."""
from __future__ import annotations

import pytest

from tools.sim_agreement import KINDS, agreement

#: Fault kinds whose simulated mean lies outside the real spread; this set may only shrink (a
#: new one fails the test). Empty since the simulated carriers' peer books record the Decisions
#: they hear, as the real carriers' do (the simulated coordinator faults kept 86-87 % without).
KNOWN_APART: set = set()


@pytest.mark.slow
def test_the_simulated_reward_kept_lies_within_the_real_spread():
    rows = agreement(missions=3)
    assert [row["fault"] for row in rows] == list(KINDS)
    apart = {row["fault"] for row in rows if not row["sim_mean_in_real_spread"]}
    assert apart == KNOWN_APART, {row["fault"]: (row["sim_mean"], min(row["real"]), max(row["real"])) for row in rows}
    assert all(len(row["sim"]) == 3 * len(row["real"]) for row in rows)  # three missions per world seed of the table
