"""A coordinator's authority: its **ballot**, ``(epoch, coordinator id)``, compared in that order
(docs/protocol.md, "Epochs" [P-7.2]).

An epoch alone is unique per mission.db, not across them: a standby on its own disk takes the
epoch above the primary's; when it dies and the primary restarts on its own, staler disk, the
primary takes that same epoch again. The coordinator id tells the two apart, so that two
coordinators' Decisions never carry one ballot, and every carrier ranks them the same way.

A coordinator of revision 5 or earlier states no id (``""``, *unstated*): its ballot is its
epoch, as before revision 6. An unstated id ranks neither above nor below a stated one of the
same epoch ([P-4.1]: an absent field means the behaviour of the revisions before it), so a
mission with a carrier of an earlier revision, whose broadcasts leave the id out, flies as at
revision 5.
"""
from __future__ import annotations

from typing import NamedTuple


class Ballot(NamedTuple):
    """``epoch`` (>= 1 once a coordinator opened the mission; 0: none heard yet) and the
    ``coordinator`` id that took it ("": not stated)."""

    epoch: int
    coordinator: str = ""

    def below(self, other: "Ballot") -> bool:
        """This ballot is older than ``other``: a lower epoch, or the same epoch and a lower id
        when both state one (its coordinator is deposed)."""
        if self.epoch != other.epoch:
            return self.epoch < other.epoch
        return bool(self.coordinator and other.coordinator) and self.coordinator < other.coordinator

    def highest(self, other: "Ballot") -> "Ballot":
        """The highest of the two, as a carrier keeps it: of an epoch, the stated id over an
        unstated one."""
        if self.below(other):
            return other
        if other.below(self):
            return self
        return self if self.coordinator or not other.coordinator else other

    def __str__(self) -> str:
        return f"{self.epoch}/{self.coordinator}" if self.coordinator else str(self.epoch)
