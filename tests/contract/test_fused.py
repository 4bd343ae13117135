"""The fused tick: the law's middle generated as one function per flight gives the
numbers of the reference jets, to rounding, on random states for every path kind.

The reference is the law flying :class:`tracker.PathTracker` (``compiled_path=False``), one
step at a time; the fused law must take its fused path on those ticks (counted), agree to
1e-9 relative on every output, and leave every fallback to the step-by-step tick.
"""

from __future__ import annotations

import math
import random
import re

import pytest

from tests.contract.test_compiled import PATHS, _normwise
from tfl_mav.build import law_config, model_params
from tfl_mav.control.path.compiled import compile_path
from tfl_mav.control.path.paths import build_path
from tfl_mav.control.tfl.fused import build_fused
from tfl_mav.control.tfl.law import TFLController
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import load_scenario

_SC = load_scenario("paper")


def _pair(path, cfg=None):
    cfg = cfg or law_config(_SC)
    ref = TFLController(model_params(_SC), path, cfg, 0.001, compiled_path=False)
    fast = TFLController(model_params(_SC), path, cfg, 0.001)
    assert fast._fused is not None
    fused = fast._fused
    hits = [0]

    def counted(*a):
        out = fused(*a)
        hits[0] += out[0] is not None     # (None, …): handed back to the step-by-step middle
        return out

    fast._fused = counted
    return ref, fast, hits


def _random_state(rng: random.Random, y0) -> State:
    """Near y0, moving, tilted up to ~15°, spinning (rates up to 3 rad/s about b1, b2 and up
    to 40 rad/s about b3, as under attack)."""
    ax = [rng.uniform(-1, 1) for _ in range(3)]
    n = math.sqrt(sum(a * a for a in ax)) or 1.0
    half = 0.5 * rng.uniform(0.0, 0.26)
    quat = (math.cos(half), *(math.sin(half) * a / n for a in ax))
    return State(tuple(c + rng.uniform(-0.05, 0.05) for c in y0),
                 tuple(rng.uniform(-0.6, 0.6) for _ in range(3)), quat,
                 (rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-40, 40)))


def _same(a, b) -> None:
    assert a.mode == b.mode and a.reason == b.reason
    assert _normwise(a.rotor_thrust_n, b.rotor_thrust_n) <= 1e-9
    assert a.saturated == b.saturated
    for u, v in [*zip(a.xi, b.xi, strict=True), (a.eta[1:], b.eta[1:]),
                 ((a.cond_d, a.thrust_n), (b.cond_d, b.thrust_n))]:
        assert _normwise(u, v) <= 1e-9
    assert b.eta[0] == pytest.approx(a.eta[0], rel=0, abs=1e-12)
    assert b.lam == pytest.approx(a.lam, rel=0, abs=1e-12 * (1 + abs(a.lam)))


@pytest.mark.parametrize("name", sorted(PATHS))
def test_fused_law_matches_the_reference_jets(name):
    kind, params, y0 = PATHS[name]
    path = build_path(kind, params)
    rng = random.Random(17)
    ticks = hits_total = 0
    for trial in range(25):
        ref, fast, hits = _pair(path)
        rotor = (0, 0, 2, 3)[trial % 4]
        for ctrl in (ref, fast):
            ctrl.set_attack(rotor, 1.0 if rotor else 0.0)
        st = _random_state(rng, y0)
        for tick in range(4):       # cold start (step by step), then warm fused ticks
            if tick:
                st = State(tuple(p + 1e-3 * v for p, v in zip(st.position_m,
                                                              st.velocity_mps, strict=True)),
                           st.velocity_mps, st.quaternion_wxyz, st.body_rates_radps)
            a, b = ref.update(st), fast.update(st)
            _same(a, b)
            ticks += a.mode is not Mode.FALLBACK
        hits_total += hits[0]
    assert ticks >= 50                  # most random states fly
    assert hits_total >= 0.6 * ticks    # … and those after the first tick ran fused


def test_fallbacks_stay_with_the_step_by_step_tick():
    """Far from the path, or with too little thrust, the fused tick bails out without
    touching anything and the law falls back exactly as the reference does."""
    kind, params, y0 = PATHS["paper"]
    path = build_path(kind, params)
    ref, fast, hits = _pair(path)
    st = State(y0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    _same(ref.update(st), fast.update(st))
    for ctrl in (ref, fast):
        ctrl.x13 = 0.1                                   # below min_thrust_n
    a, b = ref.update(st), fast.update(st)
    _same(a, b)
    assert b.mode is Mode.FALLBACK and "too small" in b.reason and hits[0] == 0
    far = State((y0[0], y0[1] + 0.5, y0[2]), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                (0.0, 0.0, 0.0))
    a, b = ref.update(far), fast.update(far)
    _same(a, b)
    assert b.mode is Mode.FALLBACK and hits[0] == 0


def test_fused_source_holds_no_scenario_text():
    """As the path kernels: only temporaries, inputs, literals, operators, the math
    functions and the template's own names reach compile()."""
    kind, params, _ = PATHS["expr-all-functions"]
    src = build_fused(model_params(_SC), compile_path(build_path(kind, params))).source
    template = set(re.findall(r"\S+", """
        def return if else not and is None for in range break abs _ try except ValueError
        ZeroDivisionError OverflowError type tolist _ndarray s position_m velocity_mps
        quaternion_wxyz body_rates_radps quat rates psi psi_ref _axes m1 m2 s1 s2 cols col
        _update_estimators fused_tick ctl trk cfg dob prev fresh lp lam lam0 step cp c arc
        distance rel cond inv speed udd pdot qdot ix iy iz y v pc qc rc mass uf duf x13 x14
        min_thrust_n max_cond speed_mps k_xi k_eta _use_dob d_p d_q _ixyz _expansion
        _lam_prev _sigma5 _arc_m min_tube_margin _arc _isfinite _atan2 _sin _cos _tan _exp
        _log _sqrt _atan _tanh _pow _abs e
        or True tau_p tau_q tau_r xi eta frame lag_inverter attack_estimate_n a_n d _d
        _alloc_att _alloc_nom _yaw_tau_r k_yaw _inv_perm i0 i1 i2 i3 raw f mode _ATTACKED
        _NOMINAL g sat0 sat1 sat2 sat3 l0 l1 l2 l3 _last_out saturation_count _perm p0 p1
        p2 p3 applied_uf d0 d1 d2
        d3 pp pq _pred dt _use_switch fine _hypot settle_alpha settle_time_s settled
        _settled_s _set_gains _mu2 iz_ arm_ den _new _ControlOutput _use_mass me mass_est lo_
        thrust _v_lp update _phi_lp nlx nly nlz npx npy npz num _inf m_inst _clamp blend
        mass_kg updates pred rprev _prev pp pq rp rq dp dq ndp ndq lx ly lz phx phy phz
        r0 r1 r2 r3 f0 f1 f2 f3 arc_m tube_min dsub_p dsub_q eta1 eta2 eta3"""))
    names = re.compile(r"[mgtqw]_\d+|q[wxyz]|r[012][012]|[xyz]\d|[xyz][xyz]|v[xyz]|b[123][xyz]"
                       r"|k[xe]\d|cp\d+|c\d+|xi[01]\d")
    code = re.sub(r"#.*", "", src)       # the template's comments
    for word in re.findall(r"[A-Za-z_][A-Za-z_0-9]*", code):
        assert word in template or names.fullmatch(word), word


def test_traced_allocation_is_the_allocation_bit_for_bit():
    """The attacked allocation traced from its own source (kernelgen.traceable: its
    conditional expressions become run-time selects) gives the float function's thrusts
    exactly, clipped or not, with the f_max = ∞ of the unbounded call at run time."""
    import math as _m

    from tfl_mav.control.allocation import allocate_attacked
    from tfl_mav.control.path.kernelgen import compile_kernel, compile_source, traceable

    alloc = traceable(allocate_attacked)
    k = compile_kernel("alloc", [["uf", "tq", "tr", "a", "d", "_inf"]],
                       lambda g: [*alloc(*g[:4], 0.2656, g[4], g[5]),
                                  *alloc(*g[:4], 0.2656, g[4], 8.0, None)], inline=True)
    fn = compile_source("alloc", k.source, {"_inf": _m.inf})
    rng = random.Random(5)
    for _ in range(2000):
        uf, tq, tr = rng.uniform(-5, 40), rng.uniform(-3, 3), rng.uniform(-0.5, 0.5)
        a, d = rng.choice([0.0, rng.uniform(0, 8)]), rng.choice([0.016, -0.016])
        want = [*allocate_attacked(uf, tq, tr, a, 0.2656, d),
                *allocate_attacked(uf, tq, tr, a, 0.2656, d, 8.0, None)]
        assert list(fn((uf, tq, tr, a, d, _m.inf))) == want
