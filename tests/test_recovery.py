"""The safe law's path projection (#13): compiled σ kernel against the reference jets.

The projector (:class:`recovery.PathProjector`) runs the same Newton steps on σ, σ', σ''
whichever evaluation it is given; the compiled ``sigma2`` kernel and the reference jets
agree to rounding, so the projection, its tangent and curvature, and the law's thrusts must
agree to rounding too — for every path kind, ``kind = "expr"`` included. The projection is
also checked to be the closest point (against a dense search), which no agreement between
two implementations can show.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from test_compiled import PATHS

from tfl_mav.build import model_params
from tfl_mav.control.compiled import compile_path
from tfl_mav.control.paths import Path, build_path
from tfl_mav.control.recovery import (
    PathProjector,
    RecoveryLaw,
    projector_sigma2,
    reference_sigma2,
)
from tfl_mav.scenario import load_scenario
from tfl_mav.state import State


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
    from tfl_mav.control.jets import Jet, cos

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
