"""Pausing exploration (an operator's ``explore/resume``, as m-explore's): what is paused, by whom, since when.

Pure state, no I/O: the launcher keeps one to serve the latest pause on ``cache/explore/resume`` and to say in its
status how long the robot has stood (``pause`` in ``launcher_status``); ``status`` and the live view word it with
``pause_note``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from cso_runtime.messages import ExploreResumeMsg

LOCKSTEP_REFUSAL = (
    "a lockstep run cannot pause: its sim waits for each step's command, and an episode held longer than "
    "lockstep_give_up_s would fail; pause a real-time run (the sim and limo-ros2 profiles)"
)
"""Why the launcher, the planner and ``cso-runtime pause`` refuse to pause a lockstep run."""


@dataclass
class PauseClock:
    """Whether exploration is paused, and for how long in all: real time goes on while paused (the sim's steps and
    the robot's scans too), so the paused seconds are reported beside the episode's figures rather than taken out."""

    latest: ExploreResumeMsg | None = None
    """The last pause or resume heard (what a restarted service learns)."""
    paused_since_s: float | None = None
    """``time.monotonic()`` when the current pause began; None while exploring."""
    paused_before_s: float = 0.0
    """Seconds paused in the pauses already resumed."""

    @property
    def paused(self) -> bool:
        return self.paused_since_s is not None

    def heard(self, msg: ExploreResumeMsg, now_s: float) -> bool:
        """Take ``msg`` (heard at ``now_s``, monotonic); whether it changed the state (a second pause is no new one)."""
        self.latest = msg
        if not msg.resume and self.paused_since_s is None:
            self.paused_since_s = now_s
            return True
        if msg.resume and self.paused_since_s is not None:
            self.paused_before_s += now_s - self.paused_since_s
            self.paused_since_s = None
            return True
        return False

    def paused_for_s(self, now_s: float) -> float:
        """Seconds of the current pause (0 while exploring)."""
        return 0.0 if self.paused_since_s is None else now_s - self.paused_since_s

    def total_s(self, now_s: float) -> float:
        """Seconds paused in all, the current pause included."""
        return self.paused_before_s + self.paused_for_s(now_s)

    def status(self, now_s: float, refused: str = "") -> dict[str, Any]:
        """``launcher_status``'s ``pause``: ``paused``, ``by``, ``reason``, ``for_s``, ``total_s`` and ``refused`` (why
        this run cannot pause; "" when it can)."""
        latest = self.latest
        return {
            "paused": self.paused,
            "by": latest.by if latest is not None and self.paused else "",
            "reason": latest.reason if latest is not None and self.paused else "",
            "for_s": round(self.paused_for_s(now_s), 3),
            "total_s": round(self.total_s(now_s), 3),
            "refused": refused,
        }


def pause_note(pause: dict[str, Any] | None) -> str:
    """What ``status`` and the live view add to the episode's state while paused (``launcher_status``'s ``pause``):
    ``; paused (by X, for N s)``; "" while exploring."""
    if not pause or not pause.get("paused"):
        return ""
    by = f"by {pause['by']}, " if pause.get("by") else ""
    why = f": {pause['reason']}" if pause.get("reason") else ""
    return f"; paused ({by}for {pause.get('for_s', 0.0):.0f} s){why}"
