"""The safe law's path projection: compiled σ kernel against the reference jets.

The projector (:class:`recovery.PathProjector`) runs the same Newton steps on σ, σ', σ''
whichever evaluation it is given; the compiled ``sigma2`` kernel and the reference jets
agree to rounding, so the projection, its tangent and curvature, and the law's thrusts must
agree to rounding too — for every path kind, ``kind = "expr"`` included. The projection is
also checked to be the closest point (against a dense search), which no agreement between
two implementations can show.

Then the take-over of a restarted controller, offline and deterministic: the
same fall the real-time test (test_faults) can only catch by chance.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from tests.contract.test_compiled import PATHS
from tfl_mav.control.path.compiled import compile_path
from tfl_mav.control.path.paths import Path, build_path
from tfl_mav.control.safe.recovery import (
    MAX_VERTICAL_G,
    POS_OMEGA,
    PathProjector,
    RecoveryLaw,
    projector_sigma2,
    reference_sigma2,
)
from tfl_mav.controller.flight_computer import TAKEOVER_TILT_RAD, FlightComputer
from tfl_mav.from_scenario import model_params
from tfl_mav.model.geometry import rotation_rows
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import apply_overrides, load_scenario
from tfl_mav.sitl.simulator import Simulator


def _rel(a, b) -> float:
    """max |a − b| / max |a| over one output vector (its scale sets what rounding means)."""
    return max(abs(x - y) for x, y in zip(a, b, strict=True)) / max(max(abs(x) for x in a),
                                                                    1e-300)


def _points(rng: random.Random, y0, n: int) -> list[tuple[float, float, float]]:
    return [tuple(c + rng.uniform(-0.3, 0.3) for c in y0) for _ in range(n)]


@pytest.mark.parametrize("name", sorted(PATHS))
def test_compiled_projection_matches_the_jets_to_rounding(name):
    kind, params, y0 = PATHS[name]
    path = build_path(kind, params)
    sig = compile_path(path).sigma2.fn
    ref_sig = reference_sigma2(path)
    rng = random.Random(13)
    for lam in (rng.uniform(*path.lam_range) for _ in range(20)):
        assert _rel(ref_sig((lam,)), sig((lam,))) <= 1e-15     # the kernel itself
    found = 0
    for y in _points(rng, y0, 40):
        ref, fast = PathProjector(path, ref_sig), PathProjector(path, sig)
        for tick in range(3):    # cold start (global search), then warm-started ticks
            yy = (y[0] + 1e-3 * tick, y[1], y[2] - 1e-3 * tick)
            a, b = ref.project(yy), fast.project(yy)
            assert (a is None) == (b is None)
            if a is None:
                break
            for u, v in zip(a[:3], b[:3], strict=True):
                assert _rel(u, v) <= 1e-9
            assert b[3] == pytest.approx(a[3], rel=1e-9, abs=1e-12)
            assert fast.lam == pytest.approx(ref.lam, rel=0, abs=1e-12 * (1 + abs(ref.lam)))
            found += 1
    assert found >= 100


@pytest.mark.parametrize("name", ["paper", "circle", "helix", "lemniscate", "expr"])
def test_projection_is_the_closest_point(name):
    """Distance, unit tangent ⟂ error and κN ⟂ T: the first-order conditions of (13), and
    no point of a dense sample of σ near λ is closer (to the sample's resolution)."""
    kind, params, y0 = PATHS[name]
    path = build_path(kind, params)
    proj = PathProjector(path)
    assert proj.evaluation == "compiled"
    for y in _points(random.Random(5), y0, 10):
        out = proj.project(y)
        assert out is not None
        p, t, kn, dist = out
        e = [y[i] - p[i] for i in range(3)]
        assert math.isclose(math.hypot(*t), 1.0, rel_tol=1e-12)
        assert abs(sum(e[i] * t[i] for i in range(3))) <= 1e-9 * (1.0 + dist)
        assert abs(sum(kn[i] * t[i] for i in range(3))) <= 1e-9 * (1.0 + math.hypot(*kn))
        lam = np.linspace(proj.lam - 0.5, proj.lam + 0.5, 20001)
        x, yy, z = (np.broadcast_to(c, lam.shape) for c in path.sigma(lam))
        dense = float(np.min(np.sqrt((x - y[0]) ** 2 + (yy - y[1]) ** 2 + (z - y[2]) ** 2)))
        assert dist <= dense + 1e-12
        assert dist == pytest.approx(dense, abs=1e-6)


def test_untraceable_path_projects_with_the_jets():
    from tfl_mav.control.path.jets import Jet, cos

    def s(x, y, z):
        return (y - cos(x), z - 5.0) if (x.c[0] if isinstance(x, Jet) else 0.0) > -1e9 \
            else (y, z)

    def sigma(lam):
        return lam, cos(lam), 5.0 + 0.0 * lam

    path = Path("custom", s, sigma, (-3.0, 3.0))
    _, note = projector_sigma2(path)
    assert note == "compiled"      # σ itself traces; only s branches
    _, note = projector_sigma2(path, compiled_path=False)
    assert note == "reference jets"


@pytest.mark.parametrize("rotor", [0, 2])
def test_the_safe_law_gives_the_same_thrusts_with_either_projection(rotor):
    """Random states near the paper path into two recovery laws (compiled / reference
    projection): the thrusts agree to 1e-9 of f_max, on four rotors and on three."""
    sc = load_scenario("paper")
    mp = model_params(sc)
    path = build_path("paper", {})
    laws = [RecoveryLaw(mp.mass_kg, mp.inertia_kgm2, mp.arm_m, mp.drag_thrust_ratio_m,
                        mp.k_t, mp.k_r, mp.thrust_max_n, mp.gravity_mps2,
                        sc.run.control_dt_s, path, 0.5, compiled_path=c) for c in (False, True)]
    assert laws[0].projector.evaluation == "reference jets"
    assert laws[1].projector.evaluation == "compiled"
    rng = random.Random(2)
    for _ in range(200):
        pos = (rng.uniform(-2, 2), 0.0, 0.0)
        pos = (pos[0], math.cos(pos[0]) + rng.uniform(-0.3, 0.3),
               8.0 - 4.0 * math.cos(pos[0]) + rng.uniform(-0.3, 0.3))
        q = [1.0] + [rng.uniform(-0.2, 0.2) for _ in range(3)]
        n = math.sqrt(sum(c * c for c in q))
        st = State(pos, tuple(rng.uniform(-1, 1) for _ in range(3)), tuple(c / n for c in q),
                   (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-60, 60)))
        a, b = (law.update(st, rotor, 0.1) for law in laws)
        assert np.allclose(a.requested_n, b.requested_n, rtol=0, atol=1e-9 * mp.thrust_max_n)
        assert np.allclose(a.thrust_n, b.thrust_n, rtol=0, atol=1e-9 * mp.thrust_max_n)
        assert b.path_distance_m == pytest.approx(a.path_distance_m, rel=1e-9)


# ------------------------------------------------------------------ restart take-over
KILL_S = 1.0          # the old controller dies here (at the paper path's lowest bend) …
HELD_S = 0.25         # … the vehicle holds its last command this long (--command-timeout) …
AFTER_S = 1.6         # … and the new controller flies this long (the old flip came at 0.8 s)


def _restart(t_off: float) -> tuple[list[Mode], list[float], list[float], State, str | None]:
    """The real-time restart test's flight, offline: a flight computer flies the nominal
    scenario from [0, 1, 4] (the path's lowest point) for ``KILL_S``; the vehicle holds
    that command for ``HELD_S``, then all four motors are cut (no torque: it falls level)
    for ``t_off``; a *fresh* flight computer takes over, told the command applied was 0 N
    (what a restarted daemon reads from ACTUATOR_OUTPUT_STATUS). Returns the modes flown,
    tilts (rad) and heights (m) from the take-over on, the take-over state, the crash."""
    sc = apply_overrides(load_scenario("nominal"), ["initial.position_m=[0,1,4]"])
    sim = Simulator(sc)
    fc = FlightComputer(sc)
    applied = list(sim.rotor_commands_n)
    for _ in range(round(KILL_S / sim.control_dt_s)):
        res = fc.step(sim.time_s, sim.measured_floats, sim.measured_rpm_floats, applied)
        sim.set_command(res.thrust_n)
        applied = list(sim.rotor_commands_n)
        sim.step_control_period()
    for _ in range(round(HELD_S / sim.control_dt_s)):
        sim.step_control_period()
    sim.set_command([0.0] * 4)
    for _ in range(round(t_off / sim.control_dt_s)):
        sim.step_control_period()
    fc = FlightComputer(sc)
    applied = [0.0] * 4
    start = sim.measured_floats
    modes, tilts, heights = [], [], []
    for _ in range(round(AFTER_S / sim.control_dt_s)):
        st = sim.measured_floats
        res = fc.step(sim.time_s, st, sim.measured_rpm_floats, applied)
        modes.append(res.mode)
        tilts.append(math.acos(max(-1.0, min(1.0, rotation_rows(st.quaternion_wxyz)[2][2]))))
        heights.append(float(st.position_m[2]))
        sim.set_command(res.thrust_n)
        applied = list(sim.rotor_commands_n)
        sim.step_control_period()
        if reason := sim.crash_reason():
            return modes, tilts, heights, start, reason
    return modes, tilts, heights, start, None


def _peak_excursion_per_mps() -> float:
    """Peak of x under the recovery law's altitude hold, the PID (s + ω_p)³ (POS_OMEGA),
    from x = 0, x' = 1 m/s, ∫x = 0: X(s) = s/(s + ω)³, x(t) = t e^{−ωt} (1 − ωt/2), whose
    largest value is at ωt = 2 − √2 (s; × the fall speed gives metres)."""
    wt = 2.0 - math.sqrt(2.0)
    return wt * math.exp(-wt) * (1.0 - wt / 2.0) / POS_OMEGA


@pytest.mark.parametrize(("t_off", "mode"), [(0.10, Mode.NOMINAL), (0.18, Mode.RECOVERY)])
def test_restarted_controller_takes_over_a_falling_vehicle_without_a_flip(t_off, mode):
    """Motors cut 0.18 s: falling level at 1.65 m/s, more than the TFL law is started from
    (it flipped 0.8 s after such a take-over, "thrust axis points down"): the recovery law
    takes it on the first tick, never tilts past its own 30° limit, and stops the fall
    within the altitude hold's peak excursion (the linear loop's, or the stopping distance at
    its 0.5 g cap) + 20 % for the levelling transient. Cut 0.10 s (0.9 m/s): TFL takes
    over directly."""
    modes, tilts, heights, start, crash = _restart(t_off)
    assert crash is None, crash
    assert modes[0] is mode
    assert max(tilts) < TAKEOVER_TILT_RAD
    v_fall = -float(start.velocity_mps[2])
    assert v_fall > 0.8                            # the case is the one it claims to be
    if mode is Mode.RECOVERY:
        # the linear loop's peak, or — where its demand meets the 0.5 g cap — the stopping
        # distance at that cap, v²/(2 a_cap), whichever is longer
        stop_m = v_fall * v_fall / (2.0 * MAX_VERTICAL_G * 9.81)
        assert heights[0] - min(heights) <= 1.2 * max(_peak_excursion_per_mps() * v_fall,
                                                      stop_m)
