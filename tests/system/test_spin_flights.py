"""The spin law flies the simulator (tfl_mav.tools.harness.spin.fly_spin): a rotor pinned high
from t = 5 s, the flight computer until the take-over, the spin law after it. Short flights
of the hardest cases of bench/bench_spin.py (which flies all 16 for 45 s)."""

from __future__ import annotations

import numpy as np
import pytest

from tfl_mav.scenario import load_scenario
from tfl_mav.tools.harness.spin import fly_spin


def _scenario(name: str, rotor: int, signal: str, mass: float, inertia: float, lag_s: float):
    return load_scenario(name).replace(**{
        "attack.rotor": rotor, "attack.signal": signal, "attack.start_s": 5.0,
        "controller.model_mass_scale": mass, "controller.model_inertia_scale": inertia,
        "vehicle.motor_time_constant_s": lag_s})


@pytest.mark.slow
@pytest.mark.parametrize(("name", "rotor", "signal", "mass", "inertia", "lag_s", "takeover_s"), [
    ("paper", 2, "5.5", 0.98, 0.9, 0.02, 5.1),   # entry 0.1 s after the attack began; the
    #                                              slow spin that once sank (docs/relaxed-hover.md)
    ("circle", 3, "8", 1.02, 1.1, 0.02, 5.0),    # another rotor: the canonical relabelling
])
def test_a_rotor_pinned_high_is_flown(name: str, rotor: int, signal: str, mass: float,
                                      inertia: float, lag_s: float, takeover_s: float) -> None:
    """No crash, never more than 2 m from the path after the take-over (the issue's limit;
    measured ≤ 0.49 m over 45 s in the bench), and the vehicle spins in the relaxed hover
    the law predicts: its rate about the body z axis within 15 % of the equilibrium's
    (the model's mass and inertia are off, so the true hover is not the model's)."""
    sc = _scenario(name, rotor, signal, mass, inertia, lag_s)
    f = fly_spin(sc, takeover_s=takeover_s, duration_s=15.0)
    assert not f.crashed, f.crash_reason
    assert f.max_distance_after(takeover_s) < 2.0
    assert f.exists is True
    late = f.t_s > 12.0
    # the rate magnitude: the spin is about the tilted axis n̄ = ω̄/Ω̄
    spin = np.linalg.norm(f.rates_radps[late], axis=1).mean()
    assert spin == pytest.approx(abs(f.spin_radps), rel=0.15)
    assert np.isfinite(f.thrusts_n).all()
