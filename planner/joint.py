"""One stage's joint actions and their sampled values: what the closed-loop planners share
(:mod:`planner.closedloop`, its coverage form :mod:`planner.closedloop_cover`, and the on-board
:mod:`planner.decentralised`)."""
from __future__ import annotations

import time

import numpy as np

#: Largest number of free carriers in one component whose 2^k joint actions are all evaluated.
ENUMERATE_MAX = 6
#: Bounds on the number of sampled futures per candidate (common to all candidates).
SAMPLES_MIN = 16
SAMPLES_MAX = 4096
#: Sampled futures per batch in the time-budget mode.
BATCH = 32


def every_combination(base: np.ndarray, flip: np.ndarray) -> np.ndarray:
    """bool ``[2^k, m]``: ``base`` with every combination of actions of the ``k`` carriers at
    positions ``flip``, ``base`` itself first (so it wins ties under ``argmax``)."""
    k = len(flip)
    codes = np.arange(1 << k)
    actions = np.repeat(base[None, :], len(codes), axis=0)
    actions[:, flip] = ((codes[:, None] >> np.arange(k)[None, :]) & 1).astype(bool)
    first = int(np.flatnonzero((actions == base).all(axis=1))[0])
    return actions[np.r_[first, np.delete(codes, first)]]



def sampled_mean(n_candidates: int, samples: int, deadline: float | None, evaluate, spread: bool = False):
    """The closed-loop planners' anytime sampling loop: the mean over sampled futures of
    ``evaluate(batch)``, float ``[n_candidates, batch]`` values of ``batch`` fresh futures (it
    draws them). Without a ``deadline`` one batch of ``samples``; with one (``time.perf_counter``
    seconds), batches of :data:`BATCH` until it passes (at least one).

    With ``spread`` it returns ``(mean, gap_se)``: also the standard error of each candidate's
    mean difference from candidate 0 on the same futures (float ``[n_candidates]``, 0 for
    candidate 0; from the paired per-sample differences)."""
    sums = np.zeros(n_candidates)
    gap_sums = np.zeros(n_candidates)
    gap_squares = np.zeros(n_candidates)
    count = 0
    while True:
        batch = samples if deadline is None else BATCH
        values = evaluate(batch)
        sums += values.sum(axis=1)
        if spread:
            gaps = values - values[:1]
            gap_sums += gaps.sum(axis=1)
            gap_squares += np.square(gaps).sum(axis=1)
        count += batch
        if deadline is None or time.perf_counter() >= deadline:
            break
    mean = sums / count
    if not spread:
        return mean
    if count < 2:
        return mean, np.zeros(n_candidates)
    gap_mean = gap_sums / count
    variance = np.maximum(gap_squares - count * np.square(gap_mean), 0.0) / (count - 1)
    return mean, np.sqrt(variance / count)
