"""Lockstep over a lossy link: a lost datagram costs milliseconds, not the 2 s timeout."""

from __future__ import annotations

import pytest

from harness.lossy import fly_through_relay

TICKS = 2000


@pytest.mark.slow
def test_one_percent_loss_costs_at_most_half_again_the_lossless_time():
    # 1 % of 2000 ticks' datagrams each way ≈ 40 losses. Each should cost one resend
    # interval (5 ms) plus a scheduler wake-up (a few ms on a loaded 2-core machine), i.e.
    # ≈ 0.4 s over a lossless run of 1-2 s; the old 2 s timeout would have cost 80 s.
    # Wall time on a shared machine is noisy, so the lossy run gets a second chance.
    clean = fly_through_relay(TICKS, 0.0)
    lossy = [fly_through_relay(TICKS, 0.01, seed=1)]
    if lossy[0]["wall_s"] > 1.5 * clean["wall_s"]:
        lossy.append(fly_through_relay(TICKS, 0.01, seed=2))
    best = min(lossy, key=lambda r: r["wall_s"])
    assert best["lost_datagrams"] >= 10       # the relay really dropped datagrams
    assert best["wall_s"] <= 1.5 * clean["wall_s"], (clean, lossy)
