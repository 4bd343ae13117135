"""Lockstep over a lossy link: a lost datagram costs milliseconds, not the 2 s timeout."""

from __future__ import annotations

import pytest

from tfl_mav.tools.harness.lossy import fly_through_relay

TICKS = 2000
# What one lost datagram may cost, wall time. Expected: one resend interval (5 ms,
# sitl/clock.py) plus a scheduler wake-up (a few ms on a loaded 2-core machine). The bound
# is 20x that and still 20x below the lockstep timeout (2 s) that a loss used to cost, so a
# resend that stopped working fails it on any machine, and a busy machine does not.
PER_LOSS_BOUND_S = 0.1


@pytest.mark.slow
def test_one_lost_datagram_costs_a_resend_not_the_timeout():
    # 1 % of 2000 ticks' datagrams each way ≈ 40 losses. An absolute cost per loss, not a
    # ratio to the lossless run: the faster the loop, the larger a fixed per-loss cost is
    # relative to it, and a ratio would fail a faster loop for being fast.
    clean = fly_through_relay(TICKS, 0.0)
    lossy = fly_through_relay(TICKS, 0.01, seed=1)
    assert lossy["lost_datagrams"] >= 10       # the relay really dropped datagrams
    per_loss = max(0.0, lossy["wall_s"] - clean["wall_s"]) / lossy["lost_datagrams"]
    assert per_loss <= PER_LOSS_BOUND_S, (clean, lossy)
