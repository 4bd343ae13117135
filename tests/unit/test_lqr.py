"""The safe law's LQR without scipy: expm, the DARE by doubling, and the gains, each
against scipy.linalg on the very models the law designs for (the whole spin schedule, both
inertia orders, 1 kHz and 250 Hz)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.linalg import expm as scipy_expm
from scipy.linalg import solve_discrete_are

from tfl_mav.control.safe import lqr, recovery
from tfl_mav.control.safe.recovery import LQR_MAX_SPIN_RADPS, LQR_Q, LQR_R, RecoveryLaw
from tfl_mav.from_scenario import model_params
from tfl_mav.model.state import State
from tfl_mav.scenario import load_scenario

MP = model_params(load_scenario("paper"))


def _model(rr: float, ix: float, iy: float) -> tuple[np.ndarray, np.ndarray]:
    iz, kr = MP.inertia_kgm2[2], MP.k_r
    a = np.array([[0.0, rr, 0.0, -1.0], [-rr, 0.0, 1.0, 0.0],
                  [0.0, 0.0, -kr / ix, -(iz - iy) * rr / ix],
                  [0.0, 0.0, -(ix - iz) * rr / iy, -kr / iy]])
    b = np.array([[0.0, 0.0], [0.0, 0.0], [1.0 / ix, 0.0], [0.0, 1.0 / iy]])
    return a, b


def _scipy_gain(a, b, dt):
    m = np.zeros((6, 6))
    m[:4, :4], m[:4, 4:] = a * dt, b * dt
    e = scipy_expm(m)
    ad, bd = e[:4, :4], e[:4, 4:]
    q, r = np.diag(LQR_Q), np.diag(LQR_R)
    p = solve_discrete_are(ad, bd, q, r)
    return np.linalg.solve(r + bd.T @ p @ bd, bd.T @ p @ ad), e


@pytest.mark.parametrize("dt", [0.001, 0.004])
def test_gains_match_scipy_over_the_schedule(dt):
    ix, iy = MP.inertia_kgm2[:2]
    for rr in np.arange(-LQR_MAX_SPIN_RADPS, LQR_MAX_SPIN_RADPS + 0.25, 2.5):
        for ixc, iyc in ((ix, iy), (iy, ix)):
            a, b = _model(rr, ixc, iyc)
            k_ref, e_ref = _scipy_gain(a, b, dt)
            ad, bd = lqr.zoh(a, b, dt)
            assert np.max(np.abs(np.hstack([ad, bd]) - e_ref[:4])) <= 1e-14
            k = lqr.dlqr(ad, bd, np.diag(LQR_Q), np.diag(LQR_R))
            assert np.max(np.abs(k - k_ref)) <= 1e-10 * np.max(np.abs(k_ref)), rr


def test_expm_and_dare_on_general_matrices():
    """Beyond the law's models: random matrices of several norms, and the DARE residual."""
    rng = np.random.default_rng(3)
    for scale in (1e-3, 0.3, 2.0, 40.0):
        m = scale * rng.standard_normal((5, 5))
        ref = scipy_expm(m)
        # e^m's condition number grows with ‖m‖ (each squaring doubles relative rounding):
        # agreement to 1e-14 per unit of norm, as two correct algorithms can agree.
        tol = 1e-14 * max(10.0, float(np.linalg.norm(m, 1)))
        assert np.max(np.abs(lqr.expm(m) - ref)) <= tol * np.max(np.abs(ref))
    for _ in range(20):
        a = rng.standard_normal((4, 4))
        b = rng.standard_normal((4, 2))
        q = np.diag(rng.uniform(0.1, 10.0, 4))
        r = np.diag(rng.uniform(0.1, 10.0, 2))
        x_ref = solve_discrete_are(a, b, q, r)
        x = lqr.solve_dare(a, b, q, r)
        assert np.max(np.abs(x - x_ref)) <= 1e-9 * np.max(np.abs(x_ref))
        res = a.T @ x @ a - a.T @ x @ b @ np.linalg.solve(r + b.T @ x @ b, b.T @ x @ a) + q - x
        assert np.max(np.abs(res)) <= 1e-9 * np.max(np.abs(x))


def test_an_unstabilizable_pair_is_an_error_not_a_loop():
    a = np.diag([2.0, 0.5])          # the unstable mode is not reached by b
    b = np.array([[0.0], [1.0]])
    with pytest.raises(ValueError, match="did not converge"):
        lqr.solve_dare(a, b, np.eye(2), np.eye(1))


def test_the_safe_law_designs_its_gains_without_scipy():
    """A restarted daemon need not import scipy: a lost-rotor tick designs its gain with
    numpy alone (checked in a fresh interpreter)."""
    code = ("import sys\n"
            "from tfl_mav.from_scenario import model_params\n"
            "from tfl_mav.control.safe.recovery import RecoveryLaw\n"
            "from tfl_mav.scenario import load_scenario\n"
            "from tfl_mav.model.state import State\n"
            "mp = model_params(load_scenario('paper'))\n"
            "law = RecoveryLaw(mp.mass_kg, mp.inertia_kgm2, mp.arm_m, mp.drag_thrust_ratio_m,"
            " mp.k_t, mp.k_r, mp.thrust_max_n, mp.gravity_mps2, 0.001, None, 0.5)\n"
            "law.hold((0.0, 0.0, 5.0))\n"
            "out = law.update(State((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),"
            " (0.1, 0.0, 40.0)), 2, 0.1)\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"


def test_the_law_uses_the_scipy_equal_gains():
    law = RecoveryLaw(MP.mass_kg, MP.inertia_kgm2, MP.arm_m, MP.drag_thrust_ratio_m, MP.k_t,
                      MP.k_r, MP.thrust_max_n, MP.gravity_mps2, 0.001, None, 0.5,
                      design_gains=False)
    law.hold((0.0, 0.0, 5.0))
    law.update(State((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.1, 0.0, 40.0)),
               2, 0.1)
    # Lazy: the gains of the block around r = 40 rad/s were designed on first use; the
    # rates of that block and the block's edges, in either canonical inertia order.
    ix, iy = MP.inertia_kgm2[:2]
    for r in (32.0, 39.5, 40.0, 40.5, 47.5):
        for ixc, iyc in ((ix, iy), (iy, ix)):
            gains = law.spin_gains(r, ixc, iyc)
            k_ref, _ = _scipy_gain(*_model(r, ixc, iyc), 0.001)
            assert np.max(np.abs(np.array(gains) - k_ref)) <= 1e-10 * np.max(np.abs(k_ref))


@pytest.mark.parametrize("inertia", [MP.inertia_kgm2, (0.0030, 0.0022, 0.0015)])
def test_the_schedule_designed_at_once_is_the_gains_one_at_a_time(inertia):
    """The whole schedule (stacked numpy calls before the flight), the blocks a lazy law
    designs when first meeting a spin rate, and a gain designed alone are the very same
    gains, bit for bit (every 7th step of each inertia order, and both ends)."""
    recovery.forget_gain_schedules()     # the lazy law designs its blocks afresh
    lazy = RecoveryLaw(MP.mass_kg, inertia, MP.arm_m, MP.drag_thrust_ratio_m, MP.k_t,
                       MP.k_r, MP.thrust_max_n, MP.gravity_mps2, 0.001, None, 0.5,
                       design_gains=False)
    top = round(recovery.LQR_MAX_SPIN_RADPS * 2.0)
    ix, iy = inertia[:2]
    orders = {(ix, iy), (iy, ix)}
    keys = [(k, ixc, iyc) for ixc, iyc in orders for k in [*range(-top, top + 1, 7), top]]
    from_blocks = {(k, ixc > iyc): lazy.spin_gains(k / 2.0, ixc, iyc) for k, ixc, iyc in keys}
    sched = recovery.gain_schedule(inertia, MP.k_r, 0.001)
    assert len(sched) == len(orders) * (2 * top + 1)
    for k, ixc, iyc in keys:
        alone = lqr.dlqr(*lqr.zoh(*recovery.spin_model(k / 2.0, ixc, iyc, inertia[2], MP.k_r),
                                  0.001), np.diag(LQR_Q), np.diag(LQR_R))
        gains = (tuple(alone[0].tolist()), tuple(alone[1].tolist()))
        assert from_blocks[(k, ixc > iyc)] == sched[(k, ixc > iyc)] == gains
