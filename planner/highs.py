"""One home for driving HiGHS (``highspy``): a silent solver and a row-wise model builder.

Used by the information-relaxation bound (:mod:`planner.duality`) and the coverage bounds
(:mod:`planner.coverage_bounds`). Pure: ``highspy`` is imported only when a model is solved.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

_BANNER_SHOWN = []  # non-empty once a Highs object exists in this process


def new_highs(highspy):
    """A silent ``highspy.Highs``. HiGHS prints a banner on stdout when the first one of a process
    is built, before any option can be set (stdout is a JSON document for ``solve``); that first
    construction runs with file descriptor 1 pointed at /dev/null."""
    import os
    import sys

    if not _BANNER_SHOWN:
        sys.stdout.flush()
        saved = os.dup(1)
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, 1)
            h = highspy.Highs()
        finally:
            os.dup2(saved, 1)
            os.close(saved)
            os.close(devnull)
        _BANNER_SHOWN.append(True)
    else:
        h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    return h


@dataclass(frozen=True)
class Solved:
    """What one HiGHS run found (raw objective units, maximisation).

    Attributes:
        optimal: HiGHS proved optimality (MIP: within ``mip_rel_gap`` 0).
        objective: the best primal objective found (-inf when none).
        bound: an upper bound on the optimum: the MIP's dual bound, or the LP optimum (+inf when
            the run stopped before having one).
        values: float ``[columns]`` the best primal solution (None when none).
    """

    optimal: bool
    objective: float
    bound: float
    values: np.ndarray | None


@dataclass
class Model:
    """A maximisation model built column by column and row by row (``lo <= a.x <= hi``)."""

    lo: list = field(default_factory=list)
    hi: list = field(default_factory=list)
    cost: list = field(default_factory=list)
    integer: list = field(default_factory=list)
    rows: list = field(default_factory=list)  # (lo, hi, [column], [coefficient])

    def var(self, cost: float, lo: float = 0.0, hi: float = 1.0, is_int: bool = False) -> int:
        """Add a column; returns its index."""
        self.lo.append(lo)
        self.hi.append(hi)
        self.cost.append(cost)
        self.integer.append(is_int)
        return len(self.cost) - 1

    def row(self, lo: float, hi: float, cols: list[int], coefs: list[float]) -> None:
        self.rows.append((lo, hi, cols, coefs))

    @property
    def nonzeros(self) -> int:
        return sum(len(r[2]) for r in self.rows)

    def solve(self, integer: bool, time_limit_s: float, max_nodes: int | None = None) -> Solved:
        """Solve with HiGHS (one thread, ``time_limit_s``); ``integer``: as a MIP (the columns
        marked integer) with a relative gap of 0, else the LP relaxation. ``max_nodes``: the MIP's
        branch and bound stops after this many nodes (1: the root node, its cuts and heuristics;
        None: no limit); a search stopped by it, unlike one stopped by the time limit, ends
        at the same dual bound on every machine."""
        import highspy  # the only HiGHS import of the planner core

        h = new_highs(highspy)
        h.setOptionValue("threads", 1)
        h.setOptionValue("time_limit", float(time_limit_s))
        if integer:
            h.setOptionValue("mip_rel_gap", 0.0)
            if max_nodes is not None:
                h.setOptionValue("mip_max_nodes", int(max_nodes))
        lp = highspy.HighsLp()
        lp.num_col_ = len(self.cost)
        lp.num_row_ = len(self.rows)
        lp.col_cost_ = np.asarray(self.cost, dtype=float)
        lp.col_lower_ = np.asarray(self.lo, dtype=float)
        lp.col_upper_ = np.asarray(self.hi, dtype=float)
        lp.row_lower_ = np.array([r[0] for r in self.rows], dtype=float)
        lp.row_upper_ = np.array([r[1] for r in self.rows], dtype=float)
        lp.sense_ = highspy.ObjSense.kMaximize
        starts, index, value = [0], [], []
        for _, _, idx, val in self.rows:
            index += idx
            value += val
            starts.append(len(index))
        lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
        lp.a_matrix_.start_ = np.asarray(starts, dtype=np.int32)
        lp.a_matrix_.index_ = np.asarray(index, dtype=np.int32)
        lp.a_matrix_.value_ = np.asarray(value, dtype=float)
        if integer:
            lp.integrality_ = [highspy.HighsVarType.kInteger if c else highspy.HighsVarType.kContinuous
                               for c in self.integer]
        h.passModel(lp)
        h.run()
        info = h.getInfo()
        optimal = h.getModelStatus() == highspy.HighsModelStatus.kOptimal
        has_primal = info.primal_solution_status == 2  # kSolutionStatusFeasible
        values = np.asarray(h.getSolution().col_value, dtype=float) if has_primal else None
        objective = float(info.objective_function_value) if has_primal else -np.inf
        if integer:
            bound = float(info.mip_dual_bound)  # +inf when the search stopped before the root LP
        else:
            bound = objective if optimal else np.inf
        return Solved(optimal, objective, bound, values)
