"""Per-trial CSV, summaries (mean ± standard error, fraction of the clairvoyant bound), plots.

The standard error of the mean is ``std(ddof=1) / sqrt(n)`` over trials. The fraction of the
clairvoyant bound is computed per trial (planner reward / clairvoyant reward of the same trial)
and then averaged; trials whose bound is 0 are left out of the fraction.
"""
from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

import numpy as np

from experiments.trials import CLAIRVOYANT

#: Columns of the per-trial CSV (one row per planner and trial).
TRIAL_FIELDS = (
    "sweep", "level", "trial", "planner", "reward", "features", "exact", "carriers", "passengers",
    "stages", "overlaps", "iterations", "seed", "planner_seed", "world_seed", "decision_ms_mean",
    "decision_ms_max", "wall_s", "deployed",
)
#: Columns of the per-trial CSVs that measure time, not decisions: they differ from run to run.
TIMING_FIELDS = ("decision_ms_mean", "decision_ms_max", "wall_s", "decision_ms_coverage", "decision_ms_penalty")
#: Columns of the summary CSV (one row per sweep level and planner).
SUMMARY_FIELDS = (
    "sweep", "level", "planner", "n", "reward_mean", "reward_sem", "features_mean", "features_sem",
    "fraction_mean", "fraction_sem", "decision_ms_mean", "decision_ms_max", "bound_exact",
)
#: Plot order and style: (label, colour, marker, line style).
STYLE = {
    "dec-closed-loop": ("Dec-closed-loop (ours)", "#66a61e", "P", "-"),
    "dec-mcts": ("Dec-MCTS", "#e6ab02", "X", "-"),
    "closed-loop": ("Closed-loop (ours)", "#1b9e77", "D", "-"),
    "closed-loop-gated": ("Closed-loop gated (ours)", "#0b5e47", "d", "-"),
    "mcts-ssap": ("MCTS-SSAP", "#d95f02", "o", "-"),
    "mcts-random": ("MCTS-Random", "#7570b3", "s", "-"),
    "ssap": ("SSAP", "#e7298a", "^", "-"),
    "random": ("Random", "#666666", "v", "-"),
    CLAIRVOYANT: ("Clairvoyant bound", "black", "", "--"),
}


def sem(values) -> float:
    """Standard error of the mean (NaN for fewer than two values)."""
    v = np.asarray(values, dtype=float)
    return float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) > 1 else float("nan")


def pm(mean: float, err: float, fmt: str = ".2f") -> str:
    """``mean ± err`` as the tables write it; the mean alone when the error is not a number (one
    trial has no standard error: never ``± nan``)."""
    return f"{mean:{fmt}} ± {err:{fmt}}" if math.isfinite(err) else f"{mean:{fmt}}"


def write_csv(rows: list[dict], path: Path, fields) -> None:
    """``rows`` (in their order) as a CSV of ``fields``; floats to 6 significant digits."""
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _fmt(row.get(k, "")) for k in fields})


def read_csv(path: Path, ints=(), floats=()) -> list[dict]:
    """Rows of a CSV with the ``ints`` and ``floats`` columns parsed back."""
    out = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            for k in ints:
                row[k] = int(row[k])
            for k in floats:
                row[k] = float(row[k])
            out.append(row)
    return out


def write_trials(rows: list[dict], path: Path) -> None:
    write_csv(sorted(rows, key=lambda r: (r["sweep"], r["level"], r["trial"], planner_order(r["planner"]))), path,
              TRIAL_FIELDS)


def read_trials(path: Path) -> list[dict]:
    """Rows of a per-trial CSV with numbers parsed back."""
    return read_csv(path, ("level", "trial", "carriers", "passengers", "stages", "overlaps", "iterations", "seed"),
                    ("reward", "features", "decision_ms_mean", "decision_ms_max", "wall_s"))


def _fmt(v):
    return f"{v:.6g}" if isinstance(v, float) else v


def planner_order(name: str) -> int:
    """Sort key of a planner name: the order of :data:`STYLE` (unknown names last); every table
    and plot of the experiments lists planners in it."""
    names = list(STYLE)
    return names.index(name) if name in names else len(names)


def summarise(rows: list[dict]) -> list[dict]:
    """One summary row per (sweep, level, planner), planners in :data:`STYLE` order."""
    bound = {(r["sweep"], r["level"], r["trial"]): r for r in rows if r["planner"] == CLAIRVOYANT}
    groups: dict = defaultdict(list)
    for r in rows:
        groups[(r["sweep"], r["level"], r["planner"])].append(r)
    out = []
    for (sweep, level, planner), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1], planner_order(kv[0][2]))):
        rewards = [r["reward"] for r in rs]
        features = [r["features"] for r in rs]
        fractions = []
        exact = []
        for r in rs:
            b = bound.get((sweep, level, r["trial"]))
            if b is not None:
                exact.append(str(b["exact"]) in ("1", "True"))
                if b["reward"] > 0:
                    fractions.append(r["reward"] / b["reward"])
        out.append({
            "sweep": sweep, "level": level, "planner": planner, "n": len(rs),
            "reward_mean": float(np.mean(rewards)), "reward_sem": sem(rewards),
            "features_mean": float(np.mean(features)), "features_sem": sem(features),
            "fraction_mean": float(np.mean(fractions)) if fractions else float("nan"),
            "fraction_sem": sem(fractions) if fractions else float("nan"),
            "decision_ms_mean": float(np.mean([r["decision_ms_mean"] for r in rs])),
            "decision_ms_max": float(np.max([r["decision_ms_max"] for r in rs])),
            "bound_exact": f"{sum(exact)}/{len(exact)}" if exact else "",
        })
    return out


def write_summary(summary: list[dict], path: Path) -> None:
    write_csv(summary, path, SUMMARY_FIELDS)


def paired(rows: list[dict], a: str, b: str) -> dict:
    """Paired comparison of planners ``a`` and ``b`` per (sweep, level): mean difference ± SEM and wins.

    Trials pair by (sweep, level, trial): both planners saw the same instance and observations.
    """
    by = defaultdict(dict)
    for r in rows:
        by[(r["sweep"], r["level"], r["trial"])][r["planner"]] = r["reward"]
    diffs = defaultdict(list)
    for (sweep, level, _), d in by.items():
        if a in d and b in d:
            diffs[(sweep, level)].append(d[a] - d[b])
    return {k: {"n": len(v), "mean": float(np.mean(v)), "sem": sem(v),
                "wins": int(np.sum(np.asarray(v) > 1e-12)), "losses": int(np.sum(np.asarray(v) < -1e-12))}
            for k, v in sorted(diffs.items())}


def markdown_table(summary: list[dict], level_name: str, features: bool = False) -> str:
    """A Markdown table: one row per level, one column per planner (mean ± SEM, fraction of bound)."""
    planners = sorted({r["planner"] for r in summary}, key=planner_order)
    levels = sorted({r["level"] for r in summary})
    cell = {(r["level"], r["planner"]): r for r in summary}
    head = f"| {level_name} | " + " | ".join(STYLE.get(p, (p,))[0] for p in planners) + " |"
    lines = [head, "|" + "---|" * (len(planners) + 1)]
    for level in levels:
        parts = []
        for p in planners:
            r = cell.get((level, p))
            if r is None:
                parts.append("")
                continue
            m, s = (r["features_mean"], r["features_sem"]) if features else (r["reward_mean"], r["reward_sem"])
            text = pm(m, s)
            if p == CLAIRVOYANT:
                if r["bound_exact"] and not r["bound_exact"].startswith(str(r["n"])):
                    text += f" (exact {r['bound_exact']}, else upper bound)"
            elif not math.isnan(r["fraction_mean"]):
                text += f" ({100 * r['fraction_mean']:.1f}%)"
            parts.append(text)
        lines.append(f"| {level} | " + " | ".join(parts) + " |")
    return "\n".join(lines)


def timing_table(summary: list[dict], level_name: str) -> str:
    """Markdown: mean decision time per stage (ms) of each planner per level (noisy: shared cores)."""
    planners = [p for p in sorted({r["planner"] for r in summary}, key=planner_order) if p != CLAIRVOYANT]
    cell = {(r["level"], r["planner"]): r for r in summary}
    lines = [f"| {level_name} | " + " | ".join(STYLE.get(p, (p,))[0] for p in planners) + " |",
             "|" + "---|" * (len(planners) + 1)]
    for level in sorted({r["level"] for r in summary}):
        cells = [f"{cell[(level, p)]['decision_ms_mean']:.1f}" if (level, p) in cell else "" for p in planners]
        lines.append(f"| {level} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def paired_table(rows: list[dict], a: str, others: list[str], level_name: str, level_label=str) -> str:
    """Markdown: mean paired difference ``a - other`` ± SEM (wins/losses) per level.

    ``level_label(level)`` writes the first column (the level itself by default).
    """
    present = {r["planner"] for r in rows}
    others = [o for o in others if o in present and o != a]
    if a not in present or not others:
        return ""
    tables = {o: paired(rows, a, o) for o in others}
    keys = sorted({k for t in tables.values() for k in t})
    label = STYLE.get(a, (a,))[0]
    lines = [f"| {level_name} | " + " | ".join(f"{label} − {STYLE.get(o, (o,))[0]}" for o in others) + " |",
             "|" + "---|" * (len(others) + 1)]
    for k in keys:
        cells = []
        for o in others:
            d = tables[o].get(k)
            cells.append("" if d is None else f"{pm(d['mean'], d['sem'], '+.3f')} ({d['wins']}/{d['losses']})")
        lines.append(f"| {level_label(k[1])} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(summary: list[dict], path: Path, xlabel: str, title: str, log_x: bool = False) -> None:
    """Two panels: mean normalised reward and fraction of the clairvoyant bound, ±1 SEM bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    planners = sorted({r["planner"] for r in summary}, key=planner_order)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    for p in planners:
        rs = sorted((r for r in summary if r["planner"] == p), key=lambda r: r["level"])
        label, colour, marker, ls = STYLE.get(p, (p, None, "x", "-"))
        x = [r["level"] for r in rs]
        axes[0].errorbar(x, [r["reward_mean"] for r in rs], yerr=[r["reward_sem"] for r in rs], label=label,
                         color=colour, marker=marker, ls=ls, capsize=3, ms=5, lw=1.5)
        if p != CLAIRVOYANT:
            axes[1].errorbar(x, [100 * r["fraction_mean"] for r in rs], yerr=[100 * r["fraction_sem"] for r in rs],
                             label=label, color=colour, marker=marker, ls=ls, capsize=3, ms=5, lw=1.5)
    axes[0].set_ylabel("mean reward (normalised, ±1 SEM)")
    axes[1].set_ylabel("% of the clairvoyant bound (±1 SEM)")
    for ax in axes:
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
        if log_x:
            ax.set_xscale("log", base=2)
            levels = sorted({r["level"] for r in summary})
            ax.set_xticks(levels)
            ax.set_xticklabels([str(v) for v in levels])
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


class Variants(NamedTuple):
    """The variants of a paired comparison: their keys (in bar order), the summary column every
    bar is a % of, and per key its colour and its legend name."""

    keys: tuple
    base: str
    colours: dict
    names: dict


def variant_bars(summary: list[dict], variants: Variants, labels: list[str], path: Path, title: str, ylabel: str,
                 figsize=(12, 4.8), lines=(100,), legend_title=None, label_size: float = 7,
                 rotation: float = 0) -> None:
    """Grouped bars of a paired comparison: per row of ``summary`` (labelled ``labels``), each
    variant's ``<v>_mean`` as a % of the row's ``variants.base`` (±1 SEM from ``<v>_sem``),
    horizontal reference ``lines`` in %."""
    base, colours, names = variants.base, variants.colours, variants.names
    variants = variants.keys
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=figsize)
    width = 0.8 / len(variants)
    for i, r in enumerate(summary):
        for k, v in enumerate(variants):
            ax.bar(i + (k - (len(variants) - 1) / 2) * width, 100 * r[f"{v}_mean"] / r[base], width,
                   yerr=100 * r[f"{v}_sem"] / r[base], color=colours[v], capsize=2,
                   label=names[v] if i == 0 else None)
    for k, y in enumerate(lines):
        ax.axhline(y, color="black", lw=0.8, ls="-" if k == 0 else ":")
    ax.set_xticks(range(len(summary)))
    ax.set_xticklabels(labels, fontsize=label_size, rotation=rotation)
    ax.set_ylabel(ylabel)
    lo = min(100 * r[f"{v}_mean"] / r[base] for r in summary for v in variants)
    ax.set_ylim(max(0.0, math.floor(lo / 10) * 10 - 10), None)
    ax.legend(fontsize=8, title=legend_title)
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
