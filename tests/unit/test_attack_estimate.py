"""The attacked rotor's thrust estimate (control/detect/attack_estimate.py): a Kalman filter
over the measured speed with the motor-lag model and the ESC noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tfl_mav.control.detect.attack_estimate import ATTACK_START, attack_params, attack_update

K_F, FMAX = 8.0e-6, 8.0
RPM = 2.0 * math.pi / 60.0


def fly(tau_s, dt_s, rpm_std, omega_true, seed=0):
    """Estimates (N) and σ (N) for the true speeds ``omega_true`` (rad/s), one a period."""
    p = attack_params(K_F, FMAX, tau_s, dt_s, rpm_std)
    rng = np.random.default_rng(seed)
    s = ATTACK_START
    est, std = [], []
    for w in omega_true:
        s, a, sd = attack_update(p, s, w + rng.normal(0.0, rpm_std * RPM))
        est.append(a)
        std.append(sd)
    return np.array(est), np.array(std)


def test_more_samples_make_the_estimate_better_not_worse():
    w = 600.0                        # 2.88 N
    errors = {}
    for hz in (250, 500, 1000):
        n = 4 * hz
        est, std = fly(0.04, 1.0 / hz, 60.0, [w] * n)
        tail = est[n // 2:] - K_F * w * w
        errors[hz] = float(np.sqrt(np.mean(tail ** 2)))
        # the filter's own σ_A is honest: within a factor 2 of the error it makes
        assert 0.5 < errors[hz] / float(np.mean(std[n // 2:])) < 2.0
    raw = 2.0 * K_F * w * 60.0 * RPM    # σ of k_f ω² read off one noisy sample
    assert errors[1000] < errors[500] < errors[250] < raw
    assert errors[1000] < raw / 2.0


def test_the_lag_model_follows_a_step_of_the_attackers_command():
    tau, dt = 0.04, 0.001
    t = np.arange(0.0, 0.6, dt)
    # the rotor's true speed: a step of the command from 400 to 800 rad/s at 0.1 s, lagged
    w = np.where(t < 0.1, 400.0, 800.0 + (400.0 - 800.0) * np.exp(-(t - 0.1) / tau))
    est, _ = fly(tau, dt, 20.0, w)
    true_f = K_F * w ** 2
    settled = t > 0.1 + 5 * tau
    assert np.max(np.abs(est[settled] - true_f[settled])) < 0.1     # of a 3.8 N step


def test_without_noise_parameters_are_refused():
    with pytest.raises(ValueError, match="rpm_noise_std"):
        attack_params(K_F, FMAX, 0.02, 0.001, 0.0)


def test_a_missing_sample_keeps_the_prediction():
    p = attack_params(K_F, FMAX, 0.0, 0.001, 30.0)
    s, a, _ = attack_update(p, ATTACK_START, 500.0)
    s, b, sd = attack_update(p, s, math.nan)
    assert math.isfinite(b) and abs(b - a) < 1e-9 and sd > 0.0
