"""Claims of a robot by runs that start at once (``cso_runtime.claims``): the verdicts, then the protocol on a router.

Runs started at the same instant in processes of their own: tests/test_runtime.py (``..._exactly_one_goes_on``).
"""

from __future__ import annotations

import threading
import time

from cso_runtime.claims import RunClaim, declare_claims, first_verdict, settle_claims, waiting_verdict
from cso_runtime.keys import robot_claim_subject, run_claim_token, run_goes_on_token
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session

A, B, C = RunClaim(1, "aa", "run-a"), RunClaim(2, "00", "run-b"), RunClaim(2, "01", "run-c")  # in this order
SUBJECT = robot_claim_subject("r0")


def test_claims_are_ordered_by_time_then_tie_break_and_read_back_from_their_keys():
    assert A < B < C
    claim = RunClaim.new("20261206-125408-lockstep-r0 (copy)")
    assert claim.run_id == "20261206-125408-lockstep-r0__copy_" and claim.chunk.split(".")[0].isdigit()
    assert sorted(c.chunk for c in (C, A, B)) == [c.chunk for c in (A, B, C)]  # the keys sort as the claims
    for key in (run_claim_token(SUBJECT, claim.chunk), run_goes_on_token(SUBJECT, claim.chunk)):
        assert RunClaim.of_key(SUBJECT, key) == claim
    assert RunClaim.of_key(robot_claim_subject("r1"), run_claim_token(SUBJECT, claim.chunk)) is None


def test_a_run_that_sees_an_earlier_claim_is_refused_and_one_that_sees_later_ones_waits_for_them():
    assert first_verdict(B, {A, B, C}) == (A, set())
    assert first_verdict(A, {A, B, C}) == (None, {B, C})
    assert first_verdict(A, {A}) == (None, set())
    assert waiting_verdict({B, C}, claimed={B, C}, going_on=set()) == (None, {B, C})  # undecided
    assert waiting_verdict({B, C}, claimed={C}, going_on=set()) == (None, {C})  # B was refused
    assert waiting_verdict({B, C}, claimed={B, C}, going_on={C}) == (C, set())  # C did not see A, and goes on
    assert waiting_verdict({B}, claimed={B, C}, going_on={C}) == (None, {B})  # C's run is not one A waits for


def test_settling_on_a_router_waits_for_later_claims_and_never_goes_on_beside_one():
    """A later claim that goes on refuses the earlier run that waited for it; one withdrawn lets it go on; one
    that never decides refuses it after ``decide_within_s``; the winner says it goes on, and holds that."""
    port = free_tcp_port()
    with (
        open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as other,
        open_session(TransportConfig(mode="client", connect=[loopback_endpoint(port)])) as session,
    ):
        later = RunClaim.new("later")
        mine = RunClaim(later.made_ns - 1, "00", "mine")
        held = declare_claims(other, [SUBJECT], later)
        tokens = declare_claims(session, [SUBJECT], mine)
        went_on, lost = settle_claims(session, [SUBJECT], mine, decide_within_s=0.3)
        assert went_on == [] and lost is not None and lost.winner == later and lost.undecided
        gone_on = other.liveliness().declare_token(run_goes_on_token(SUBJECT, later.chunk))
        went_on, lost = settle_claims(session, [SUBJECT], mine)
        assert went_on == [] and lost is not None and lost.winner == later and not lost.undecided
        gone_on.undeclare()
        withdrawn = threading.Thread(target=held[0].undeclare)  # while this run waits, or before it looks: the same
        withdrawn.start()
        went_on, lost = settle_claims(session, [SUBJECT], mine)
        withdrawn.join()
        assert lost is None and len(went_on) == 1
        deadline_s = time.monotonic() + 10.0  # the router hears of the client's token a moment after it is declared
        while not (going_on := [str(r.ok.key_expr) for r in other.liveliness().get(run_goes_on_token(SUBJECT), timeout=1.0) if r.ok]):
            assert time.monotonic() < deadline_s, "the router never heard that the run goes on"
            time.sleep(0.02)
        assert going_on == [run_goes_on_token(SUBJECT, mine.chunk)]
        assert not [r for r in other.liveliness().get("cso/**", timeout=1.0) if r.ok]  # no robot's keys: a verbatim chunk
        for token in [*tokens, *went_on]:
            token.undeclare()
