"""How a carrier's run ends: its exit reasons, the process exit code each maps to, the exit a
refused Hello means and the exit reason of a run an exception ended."""
from __future__ import annotations

from mission.exits import STOPPED

#: Exit reasons and the process exit code each maps to.
EXIT_CODES = {"end": 0, "finished": 0, "stopped": STOPPED, "coordinator-lost": 1, "world-mismatch": 2, "refused": 2,
              "log-mismatch": 2, "ros2-mismatch": 2}


class Exit(Exception):
    """Leave the run loop with an exit reason (a key of :data:`EXIT_CODES`)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def refused_exit(refused, fingerprint: str, log) -> None:
    """End the run when the coordinator refused the carrier's Hello (``refused``: its Refusal,
    None: not refused): ``world-mismatch`` for another world (with what to do about it),
    ``refused`` otherwise; one log line either way."""
    if refused is None:
        return
    if refused.reason != "world-mismatch":
        log(f"the coordinator refused our Hello ({refused.reason}: {refused.detail})")
        raise Exit("refused")
    log(f"the coordinator refused our Hello ({refused.reason}: fingerprint {fingerprint}, "
        f"the coordinator's {refused.expected}): use the same scenario file and --seed")
    raise Exit("world-mismatch")


def exit_reason(exc: Exception, log) -> str:
    """The exit reason of a run that ``exc`` ended: an :class:`Exit`'s, or the one a body's error
    names (its ``exit_reason``: a robot of another ROS 2 format), logged (``log``: a callable
    taking one line); any other exception is raised again."""
    if isinstance(exc, Exit):
        return exc.reason
    reason = getattr(exc, "exit_reason", None)
    if reason not in EXIT_CODES:
        raise exc
    log(str(exc))
    return reason
