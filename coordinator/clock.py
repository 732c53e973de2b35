"""What the coordinator's stage clock is set with: the waits of its lifecycle machine
(:mod:`mission.coordinator_life`: the carriers' join, the stages, the last Confirms, End and the
Byes, each wait a rule of :mod:`mission.timers` called by the machine; the process feeds it its
clock: :meth:`coordinator.node.Coordinator.fly`), its poll, and the stage's progress line.

Two clocks (docs/fleet.md, "Simulated time and wall time"): on the ``sim`` clock a live carrier
that makes progress is waited for and only a failure (its token gone, or nothing from it for
``silence_timeout_s``: :func:`mission.peers.last_heard`) ends a wait; on the ``wall`` clock the
timeouts are deadlines.
"""
from __future__ import annotations

import dataclasses

from mission import state as ms
from mission.timeouts import DEFAULTS, Timeouts


#: Longest the coordinator waits for inbox items before it looks at its clock again (s).
POLL_S = 0.05


def waits_of(config) -> Timeouts:
    """The waits of :mod:`mission.coordinator_life` a coordinator of ``config`` times by."""
    return dataclasses.replace(DEFAULTS, join_s=float(config.join_timeout_s), stage_s=float(config.stage_timeout_s),
                               confirm_s=float(config.confirm_timeout_s), silence_s=float(config.silence_timeout_s),
                               bye_s=float(config.bye_timeout_s), bye_grace_s=float(config.bye_grace_s),
                               end_repeat_s=float(config.end_repeat_s), rejoin_s=config.rejoin_timeout_s)


def progress_line(spec: ms.MissionSpec, st: ms.MissionState, j: int, waited_ms: float) -> str:
    """The console's line of stage j, decided in ``st`` after a wait of ``waited_ms``."""
    d = st.decisions[j]
    obs = []
    for r, cid in enumerate(spec.carriers):
        if spec.valid[r][j]:
            value = st.reported.get((cid, j))
            obs.append(f"{cid}={'∅' if value is None else value}")
    # Confirmations of the previous stage's deployments. Stage numbers count from 0 everywhere
    # (the wire, summary.json, map.png and this line): stage j of 0..N-1.
    confirmed = sorted(cid for (cid, jj), conf in st.confirms.items() if jj == j - 1 and conf.deployed)
    return (
        f"stage {j:>3} of 0..{spec.n_stages - 1} t={spec.stage_times[j]:7.1f} s | "
        f"obs {' '.join(obs) or '-'} | deploy {' '.join(d.deploy) or '-'} | plan {d.planning_ms:7.1f} ms | "
        f"wait {waited_ms:6.0f} ms"
        + (f" | deployed@{j - 1}: {' '.join(confirmed) or '-'}" if j > 0 else "")
    )
