"""Claims that let exactly one of several runs started at once on one network take a robot.

``up`` refuses a run whose robot id another run already has, or whose ROS 2 bridge would drive a robot another run
drives (``Launcher.robot_already_served``). Asking is not enough on its own: two runs started at the same instant
each asked before the other had declared anything, and both went on. So a run first claims what it is to run (a
liveliness token per subject, ``keys.run_claim_token``), and only then asks. A router handles one session's
declarations and queries in the order they were sent, so of two runs that claim at once, at least one sees the
other's claim; which one goes on must then not depend on who saw whom:

- a run that sees an earlier claim (``RunClaim`` order: the time it was made, then a random tie-break) is refused;
- a run that sees only later claims waits until each of them has decided: a claim withdrawn (that run was refused,
  or has ended) no longer counts; one that goes on (``keys.run_goes_on_token``) refuses this run;
- a run that wins says so for each subject, and holds its claims and those tokens until a run started later can
  see it otherwise (``Launcher.seen_at_router``: its launcher answers for the robot id).

A ROS 2 bridge started by hand claims the robot it drives the same way (``Ros2BridgeService.claim_robot``).

Of two runs that claim at once, the later one goes on only when it has not seen the earlier one, which has then seen
it and waits for its decision; every run orders the claims the same way, whatever the hosts' clocks say. This holds
for sessions that are clients of one router (``up`` claims on such a session): a router answers a liveliness query
from what it knows, and a claim made through another router (a run's own, joined to it) may not have reached it yet.
"""

from __future__ import annotations

import re
import secrets
import threading
import time
from dataclasses import dataclass
from typing import Any

from cso_runtime.keys import RUN_CLAIMS, run_claim_token, run_goes_on_token

DECIDE_WITHIN_S = 30.0
"""How long a run waits for a later claim's run to decide (it does within a second or two; a loaded host's may take
longer) before it gives up and is refused: a run never goes on while another might."""

POLL_S = 0.05
"""How often a waiting run asks again."""


@dataclass(frozen=True, order=True)
class RunClaim:
    """One run's claim, ordered by when it was made (Unix time, ns), then by a random tie-break; its ``run_id`` (in key
    characters) says who claimed."""

    made_ns: int
    tie_break: str
    run_id: str

    @classmethod
    def new(cls, run_id: str) -> RunClaim:
        return cls(time.time_ns(), secrets.token_hex(4), re.sub(r"[^A-Za-z0-9_.-]", "_", run_id))

    @property
    def chunk(self) -> str:
        """The claim as one key chunk, in the claims' order (a zero-padded time first)."""
        return f"{self.made_ns:020d}.{self.tie_break}.{self.run_id}"

    @classmethod
    def of_key(cls, subject: str, key_expr: str) -> RunClaim | None:
        """The claim a claim's (or its go-on) token key names on ``subject``, or None for a key of another form."""
        chunks = str(key_expr).split("/")
        if len(chunks) < 3 or "/".join(chunks[:2]) != RUN_CLAIMS or not str(key_expr).endswith(f"/{subject}"):
            return None
        made, _, rest = chunks[2].partition(".")
        tie_break, _, run_id = rest.partition(".")
        return cls(int(made), tie_break, run_id) if made.isdigit() and tie_break and run_id else None


@dataclass(frozen=True)
class LostClaim:
    """Why a run does not get ``subject``: ``winner``'s run has it (an earlier claim, or one that goes on), or it is
    ``undecided`` (a later claim whose run did not decide within ``DECIDE_WITHIN_S``), or this run was ``stopped``."""

    subject: str
    winner: RunClaim
    undecided: bool = False
    stopped: bool = False


def first_verdict(mine: RunClaim, seen: set[RunClaim]) -> tuple[RunClaim | None, set[RunClaim]]:
    """After this run claimed and looked: the earliest claim made before ``mine`` (this run is refused), or None and
    the later claims whose runs' decisions this run waits for."""
    others = seen - {mine}
    earlier = [c for c in others if c < mine]
    return (min(earlier), set()) if earlier else (None, others)


def waiting_verdict(waiting_for: set[RunClaim], claimed: set[RunClaim], going_on: set[RunClaim]) -> tuple[RunClaim | None, set[RunClaim]]:
    """While this run waits for later claims' decisions, from what is ``claimed`` and ``going_on`` now: one that goes on
    (this run is refused), or None and those still undecided (none left: this run goes on)."""
    won = sorted(waiting_for & going_on)
    return (won[0], set()) if won else (None, waiting_for & claimed)


def declare_claims(session: Any, subjects: list[str], claim: RunClaim) -> list[Any]:
    """This run's claim on each subject (liveliness tokens, to hold while it runs), before it asks about any."""
    return [session.liveliness().declare_token(run_claim_token(subject, claim.chunk)) for subject in subjects]


def _claims(session: Any, key_expr: str, subject: str, timeout_s: float) -> set[RunClaim]:
    """The claims on ``subject`` whose tokens match ``key_expr`` now (claims, or the go-ons of claims)."""
    found = (RunClaim.of_key(subject, str(reply.ok.key_expr)) for reply in session.liveliness().get(key_expr, timeout=timeout_s) if reply.ok is not None)
    return {c for c in found if c is not None}


def settle_claims(
    session: Any,
    subjects: list[str],
    claim: RunClaim,
    timeout_s: float = 1.0,
    decide_within_s: float = DECIDE_WITHIN_S,
    stop: threading.Event | None = None,
) -> tuple[list[Any], LostClaim | None]:
    """Whether this run, whose claims are declared (``declare_claims``), gets every subject: the go-on tokens of those
    it won (to hold while it runs), and the first it lost (None: it won all)."""
    stop = stop if stop is not None else threading.Event()
    went_on: list[Any] = []
    for subject in subjects:
        earlier, waiting_for = first_verdict(claim, _claims(session, run_claim_token(subject), subject, timeout_s))
        if earlier is not None:
            return went_on, LostClaim(subject, earlier)
        deadline_s = time.monotonic() + decide_within_s
        while waiting_for:
            going_on = _claims(session, run_goes_on_token(subject), subject, timeout_s)
            winner, waiting_for = waiting_verdict(waiting_for, _claims(session, run_claim_token(subject), subject, timeout_s), going_on)
            if winner is not None:
                return went_on, LostClaim(subject, winner)
            if not waiting_for:
                break
            if time.monotonic() > deadline_s:
                return went_on, LostClaim(subject, min(waiting_for), undecided=True)
            if stop.wait(POLL_S):
                return went_on, LostClaim(subject, min(waiting_for), stopped=True)
        went_on.append(session.liveliness().declare_token(run_goes_on_token(subject, claim.chunk)))
    return went_on, None
