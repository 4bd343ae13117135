"""The air the vehicle flies in: mean wind + Dryden turbulence + a discrete 1 − cos gust.

All velocities in m/s, paper frame (inertial, z up). The turbulence follows the Dryden form
of MIL-F-8785C §3.7 (and MIL-HDBK-1797 App. A, which writes the same spectra with half the
lateral/vertical scale lengths), low-altitude model (h < 1000 ft):

    L_w = h,  L_u = L_v = h / (0.177 + 0.000823 h)^1.2            (h, L in ft)
    σ_w = 0.1 W₂₀,  σ_u = σ_v = σ_w / (0.177 + 0.000823 h)^0.4
    W₂₀ (wind speed at 20 ft): light 15 kt, moderate 30 kt, severe 45 kt

with the one-sided power spectral densities in ω (rad/s) of the temporal process seen at
airspeed V (Taylor's frozen-turbulence hypothesis):

    Φ_u(ω) = σ_u² (2 L_u / (π V)) / (1 + (L_u ω / V)²)
    Φ_v(ω) = σ_v² (L_v / (π V)) (1 + 3 (L_v ω / V)²) / (1 + (L_v ω / V)²)²      (w alike)

(:func:`dryden_psd`; each integrates to σ² over ω ∈ [0, ∞)). The scales are evaluated at
:data:`REFERENCE_ALTITUDE_M` = 20 ft, where W₂₀ is defined (the paper path flies 4–12 m);
V is the mean wind speed, at least :data:`MIN_AIRSPEED_MPS` (a hovering vehicle sees the
turbulence carried past it by the mean wind; RotorPy's ``DrydenWind`` uses 1 m/s). u is
along the horizontal mean wind (x when there is none), v horizontal across it, w up.

Each component is the exact discretisation, at :data:`TURBULENCE_HZ`, of its shaping filter
driven by white noise (u: a first-order Gauss–Markov process; v, w: the two-state
realisation of σ √(L/(πV)) (1 + √3 T s)/(1 + T s)², T = L/V, with the noise covariance of
one sample interval by Van Loan's method), started from its stationary distribution, so the
sampled process has the Dryden autocorrelation at every lag. It is interpolated linearly to
the physics steps. The draws come from their own stream seeded by ``run.seed``: the wind
does not move the sensors' noise, and a seed replays the same air bit for bit.

The gust (MIL-F-8785C §3.7.4's 1 − cos shape, up and down again, as FAR 25.341's):
``gust(t) = gust_mps · (1 − cos(2π (t − t₀)/T_g)) / 2`` for t₀ ≤ t ≤ t₀ + T_g, peak
``gust_mps`` at mid-gust.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tfl_mav.scenario import WindConfig

__all__ = ["MIN_AIRSPEED_MPS", "REFERENCE_ALTITUDE_M", "TURBULENCE_HZ", "DrydenScales",
           "WindField", "dryden_psd", "dryden_scales"]

FT = 0.3048                      # m per ft
KNOT = 0.514444                  # m/s per knot
REFERENCE_ALTITUDE_M = 20 * FT   # where W₂₀ is defined
MIN_AIRSPEED_MPS = 1.0
TURBULENCE_HZ = 100.0
# W₂₀ of MIL-F-8785C fig. 10 / MIL-HDBK-1797 fig. 261 (probability of exceedance 10⁻², 10⁻³,
# 10⁻⁵ in the handbook's wording: light, moderate, severe).
W20_KNOTS = {"light": 15.0, "moderate": 30.0, "severe": 45.0}
# A stream of its own under run.seed ("WIND"): the sensors keep their numbers.
_STREAM = 0x57494E44
_BLOCK_S = 1.0                   # turbulence generated a second at a time


class DrydenScales(NamedTuple):
    """Intensities (m/s) and scale lengths (m) of the three components, and the airspeed V
    (m/s) that turns the spatial spectra into temporal ones."""

    sigma_mps: tuple[float, float, float]     # σ_u, σ_v, σ_w
    length_m: tuple[float, float, float]      # L_u, L_v, L_w
    airspeed_mps: float


def dryden_scales(turbulence: str, mean_mps: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  altitude_m: float = REFERENCE_ALTITUDE_M) -> DrydenScales:
    """The low-altitude Dryden intensities and scales of a turbulence level (module doc)."""
    h_ft = max(altitude_m / FT, 10.0)      # the low-altitude model holds from 10 ft
    den = 0.177 + 0.000823 * h_ft
    sigma_w = 0.1 * W20_KNOTS.get(turbulence, 0.0) * KNOT
    sigma_uv = sigma_w / den ** 0.4
    l_w = h_ft * FT
    l_uv = h_ft / den ** 1.2 * FT
    v = max(math.sqrt(sum(c * c for c in mean_mps)), MIN_AIRSPEED_MPS)
    return DrydenScales((sigma_uv, sigma_uv, sigma_w), (l_uv, l_uv, l_w), v)


def dryden_psd(axis: int, omega_radps: np.ndarray, sigma_mps: float, length_m: float,
               airspeed_mps: float) -> np.ndarray:
    """One-sided PSD ((m/s)²/(rad/s)) of component ``axis`` (0 u, 1 v, 2 w) at ω ≥ 0."""
    x = length_m * np.asarray(omega_radps, dtype=float) / airspeed_mps
    if axis == 0:
        return sigma_mps ** 2 * 2.0 * length_m / (math.pi * airspeed_mps) / (1.0 + x * x)
    return (sigma_mps ** 2 * length_m / (math.pi * airspeed_mps)
            * (1.0 + 3.0 * x * x) / (1.0 + x * x) ** 2)


def _expm(a: np.ndarray) -> np.ndarray:
    """Matrix exponential (scaling and squaring of a Taylor series; small matrices)."""
    norm = float(np.abs(a).sum(axis=1).max())
    s = max(0, math.ceil(math.log2(norm)) + 1) if norm > 0.5 else 0
    b = a / (2.0 ** s)
    out = np.eye(len(a))
    term = np.eye(len(a))
    for k in range(1, 20):
        term = term @ b / k
        out = out + term
    for _ in range(s):
        out = out @ out
    return out


def _sqrt_psd(m: np.ndarray) -> np.ndarray:
    """G with G Gᵀ = m for a symmetric positive semi-definite m (round-off negatives → 0)."""
    lam, vec = np.linalg.eigh(0.5 * (m + m.T))
    return vec * np.sqrt(np.clip(lam, 0.0, None))


class _Shaper(NamedTuple):
    """One component's exact discrete model: x ← Φ x + G n, y = c·x (n ~ N(0, I))."""

    phi: tuple[tuple[float, ...], ...]
    g: tuple[tuple[float, ...], ...]
    c: tuple[float, ...]
    p0: np.ndarray            # stationary covariance of x (for the first state)


def _shaper(axis: int, sigma: float, length: float, airspeed: float, dt: float) -> _Shaper:
    t = length / airspeed
    if axis == 0:           # σ √(2L/(πV)) / (1 + T s): Gauss–Markov, variance σ²
        a = math.exp(-dt / t)
        return _Shaper(((a,),), ((sigma * math.sqrt(1.0 - a * a),),), (1.0,),
                       np.array([[sigma * sigma]]))
    # (1 + √3 T s)/(1 + T s)² in controllable form, scaled to variance σ² below
    a_c = np.array([[0.0, 1.0], [-1.0 / t ** 2, -2.0 / t]])
    b_c = np.array([[0.0], [1.0]])
    c = np.array([1.0 / t ** 2, math.sqrt(3.0) / t])
    # Van Loan: exp([[-A, BBᵀ], [0, Aᵀ]] dt) = [[·, Φ⁻¹Q], [0, Φᵀ]]
    m = np.zeros((4, 4))
    m[:2, :2], m[:2, 2:], m[2:, 2:] = -a_c, b_c @ b_c.T, a_c.T
    e = _expm(m * dt)
    phi = e[2:, 2:].T
    q = phi @ e[:2, 2:]
    # stationary covariance of the continuous state, A P + P Aᵀ + B Bᵀ = 0 (closed form for
    # the double pole −1/T): P = [[T³/4, 0], [0, T/4]]
    p = np.array([[t ** 3 / 4.0, 0.0], [0.0, t / 4.0]])
    scale = sigma / math.sqrt(float(c @ p @ c))
    g = _sqrt_psd(q)
    return _Shaper(tuple(map(tuple, phi.tolist())), tuple(map(tuple, g.tolist())),
                   tuple((scale * c).tolist()), p)


class WindField:
    """The wind of one flight, sampled at consecutive physics steps (:meth:`at`).

    Deterministic: the same :class:`~tfl_mav.scenario.WindConfig`, seed and step give the
    same floats, whatever else the flight does (the air does not depend on the vehicle).
    """

    def __init__(self, cfg: WindConfig, seed: int, physics_dt_s: float) -> None:
        self.cfg = cfg
        self.physics_dt_s = physics_dt_s
        self.mean_mps = tuple(float(c) for c in cfg.mean_mps)
        self.scales = dryden_scales(cfg.turbulence, cfg.mean_mps)
        self.turbulent = cfg.turbulence != "none"
        self.gust = cfg.gust_duration_s > 0.0 and any(c != 0.0 for c in cfg.gust_mps)
        mx, my = self.mean_mps[0], self.mean_mps[1]
        horiz = math.hypot(mx, my)
        ux, uy = (mx / horiz, my / horiz) if horiz > 0.0 else (1.0, 0.0)
        # u along the horizontal mean, v across it (z × u), w up: paper-frame unit vectors
        self._axes = np.array([[ux, uy, 0.0], [-uy, ux, 0.0], [0.0, 0.0, 1.0]])
        self._turb_dt = 1.0 / TURBULENCE_HZ
        self._block_n = round(_BLOCK_S * TURBULENCE_HZ)
        self._rng = np.random.default_rng((seed, _STREAM))
        if self.turbulent:
            s = self.scales
            self._shapers = [_shaper(i, s.sigma_mps[i], s.length_m[i], s.airspeed_mps,
                                     self._turb_dt) for i in range(3)]
            # the first state from the stationary distribution: turbulence is there at t = 0
            self._x = [(_sqrt_psd(sh.p0) @ self._rng.standard_normal(len(sh.p0))).tolist()
                       for sh in self._shapers]
            self._last = self._output()            # turbulence at the block's start
        self._k0 = 0                               # first turbulence sample of the block
        self._n0 = 0                               # first physics step of the buffer
        self._buf: list[tuple[float, float, float]] = []
        self._fill()

    # ---------------------------------------------------------------- turbulence
    def _output(self) -> tuple[float, float, float]:
        (cu,), (cv1, cv2), (cw1, cw2) = (sh.c for sh in self._shapers)
        (xu,), (xv1, xv2), (xw1, xw2) = self._x
        return (cu * xu, cv1 * xv1 + cv2 * xv2, cw1 * xw1 + cw2 * xw2)

    def _block(self) -> list[tuple[float, float, float]]:
        """The next :attr:`_block_n` turbulence samples (u, v, w), m/s: one draw of all
        their noise (5 normals a sample: 1 for u, 2 each for v and w), then the
        recursions x ← Φ x + G n written out on floats."""
        su, sv, sw = self._shapers
        ((au,),), ((gu,),) = su.phi, su.g
        (cu,) = su.c
        (xu,), (v1, v2), (w1, w2) = self._x
        (pv11, pv12), (pv21, pv22) = sv.phi
        (gv11, gv12), (gv21, gv22) = sv.g
        cv1, cv2 = sv.c
        (pw11, pw12), (pw21, pw22) = sw.phi
        (gw11, gw12), (gw21, gw22) = sw.g
        cw1, cw2 = sw.c
        out = []
        append = out.append
        for nu, na, nb, nc, nd in self._rng.standard_normal((self._block_n, 5)).tolist():
            xu = au * xu + gu * nu
            v1, v2 = (pv11 * v1 + pv12 * v2 + (gv11 * na + gv12 * nb),
                      pv21 * v1 + pv22 * v2 + (gv21 * na + gv22 * nb))
            w1, w2 = (pw11 * w1 + pw12 * w2 + (gw11 * nc + gw12 * nd),
                      pw21 * w1 + pw22 * w2 + (gw21 * nc + gw22 * nd))
            append((cu * xu, cv1 * v1 + cv2 * v2, cw1 * w1 + cw2 * w2))
        self._x = [[xu], [v1, v2], [w1, w2]]
        return out

    def turbulence_samples(self, blocks: int) -> np.ndarray:
        """The next ``blocks`` blocks of turbulence samples (u, v, w) at
        :data:`TURBULENCE_HZ` (a second a block), shape (N, 3), m/s: the generator the
        flight reads, for the test of its spectra. Only on a field not yet flown."""
        return np.array([s for _ in range(blocks) for s in self._block()])

    # ---------------------------------------------------------------- the buffer
    def _fill(self) -> None:
        """The wind at the physics steps of the next block (mean + turbulence + gust)."""
        h = self.physics_dt_s
        k0 = self._k0
        kn = self._block_n
        # physics steps n with t = n h in [k0, k0 + kn) turbulence intervals
        n_start = self._n0 + len(self._buf)
        t_end = (k0 + kn) * self._turb_dt
        n_end = max(n_start + 1, math.ceil(t_end / h - 1e-9))
        t = np.arange(n_start, n_end, dtype=float) * h
        w = np.tile(np.asarray(self.mean_mps), (len(t), 1))
        if self.turbulent:
            knots = [self._last, *self._block()]
            tk = (k0 + np.arange(kn + 1)) * self._turb_dt
            uvw = np.array(knots)
            local = np.stack([np.interp(t, tk, uvw[:, i]) for i in range(3)], axis=1)
            w = w + local @ self._axes
            self._last = knots[-1]
        if self.gust:
            c = self.cfg
            tau = (t - c.gust_start_s) / c.gust_duration_s
            inside = (tau >= 0.0) & (tau <= 1.0)
            shape = np.where(inside, 0.5 * (1.0 - np.cos(2.0 * math.pi * tau)), 0.0)
            w = w + shape[:, None] * np.asarray(c.gust_mps)[None, :]
        self._n0 = n_start
        self._buf = [tuple(r) for r in w.tolist()]   # type: ignore[misc]
        self._k0 = k0 + kn

    def at(self, n: int) -> tuple[float, float, float]:
        """The wind (m/s, paper frame) at physics step ``n`` (t = n·dt). Steps are read in
        order: ``n`` no earlier than the buffer's first step (a step already passed and
        dropped raises IndexError)."""
        i = n - self._n0
        buf = self._buf
        while i >= len(buf):
            self._fill()
            buf = self._buf
            i = n - self._n0
        if i < 0:
            raise IndexError(f"wind at step {n}: already passed (the field moves forward)")
        return buf[i]

    def series(self, steps: np.ndarray) -> np.ndarray:
        """The wind at increasing physics steps ``steps`` (m/s, shape (N, 3)), for logs."""
        return np.array([self.at(int(n)) for n in steps]).reshape(-1, 3)
