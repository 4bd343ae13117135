"""Battery and ESC electrical model: plausible voltage, current and temperature telemetry.

Nothing in the flight depends on it; it exists so ``ESC_TELEMETRY_1_TO_4`` and
``SYS_STATUS`` carry numbers a ground station and a detector can treat as real, and so an
attacked rotor shows in current as well as rpm. It is a function of the *true* rotor speeds
(not the commands), integrated on sim time, so lockstep runs stay deterministic.

    shaft power     P_i = τ_i ω_i = d k_f ω_i³        (drag torque τ = d·f, as in the mixer)
    ESC current     I_i = P_i / (η V) + I_idle         (η: motor + ESC efficiency)
    battery         V = V_oc(soc) − R_int Σ I_i,  V_oc linear from full to empty
    ESC temperature dT/dt = (T_amb + k_T I_i − T) / τ_T (exact first-order step)

Defaults: a 4S 5000 mAh LiPo (16.8 V full, 14.0 V empty, 20 mΩ), η = 0.7 — about 9 A at
hover for the paper's 1.1 kg vehicle.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

__all__ = ["PowerModel", "PowerSample"]


class PowerSample(NamedTuple):
    """One evaluation of the electrical state (SI and pack units as named); a NamedTuple
    because the vehicle makes one every tick."""

    voltage_v: float                  # battery terminal voltage (V), seen by every ESC
    currents_a: tuple[float, ...]     # per ESC (A)
    consumed_mah: tuple[float, ...]   # per ESC since start (mAh)
    temperatures_c: tuple[float, ...]  # per ESC (°C)
    remaining_pct: float              # battery state of charge (0-100 %)

    @property
    def total_current_a(self) -> float:
        return sum(self.currents_a)


_new = tuple.__new__


class PowerModel:
    """Battery + four ESCs. Call :meth:`step` once per control period with true ω."""

    def __init__(self, *, drag_thrust_ratio_m: float, k_f: float, cells: int = 4,
                 capacity_mah: float = 5000.0, cell_full_v: float = 4.2,
                 cell_empty_v: float = 3.5, internal_resistance_ohm: float = 0.02,
                 efficiency: float = 0.7, idle_current_a: float = 0.2,
                 ambient_c: float = 25.0, heating_c_per_a: float = 3.0,
                 thermal_time_constant_s: float = 20.0) -> None:
        self.torque_coeff = drag_thrust_ratio_m * k_f   # N m / (rad/s)^2
        self.full_v = cells * cell_full_v
        self.empty_v = cells * cell_empty_v
        self.capacity_mah = capacity_mah
        self.r_int_ohm = internal_resistance_ohm
        self.efficiency = efficiency
        self.idle_current_a = idle_current_a
        self.ambient_c = ambient_c
        self.heating_c_per_a = heating_c_per_a
        self.thermal_tau_s = thermal_time_constant_s
        self._consumed_mah = (0.0,) * 4
        self._temps_c = (ambient_c,) * 4
        self._dt_s = math.nan            # the step's constants, computed for this dt
        self._mah_per_a = 0.0
        self._decay = 1.0
        self._voltage_v = self.full_v
        self.sample = PowerSample(self.full_v, (0.0,) * 4, (0.0,) * 4, (ambient_c,) * 4, 100.0)

    def step(self, omega_radps: Sequence[float], dt_s: float) -> PowerSample:
        """Advance by ``dt_s`` s with the rotors at ``omega_radps`` (rad/s); return the sample.

        The ESC currents use the previous step's terminal voltage (one step of lag keeps the
        update explicit; at 1 kHz the difference is far below the telemetry resolution).
        The arithmetic is :func:`power_step`, compiled to C when it can be
        (:mod:`tfl_mav.accel.native`: the same operations in the same order, the same bits).
        """
        if dt_s != self._dt_s:       # constants of the step: dt is the same every tick
            self._dt_s = dt_s
            self._mah_per_a = 1000.0 * dt_s / 3600.0
            self._decay = math.exp(-dt_s / self.thermal_tau_s)
        args = (omega_radps, self._consumed_mah, self._temps_c, self._voltage_v,
                self.torque_coeff, self.efficiency, self.idle_current_a, self._mah_per_a,
                self._decay, self.ambient_c, self.heating_c_per_a, self.capacity_mah,
                self.empty_v, self.full_v, self.r_int_ohm)
        core = _native["core"]
        r = core(*args) if core is not None else None
        if r is None:                 # not compiled, or an operation Python raises for
            r = power_step(*args)
        self._voltage_v, _, self._consumed_mah, self._temps_c, _ = r
        # tuple.__new__: the NamedTuple's generated __new__ is a Python call (every tick)
        self.sample = sample = _new(PowerSample, r)
        return sample


def power_step(omega_radps, consumed_mah, temps_c, voltage_v, torque_coeff,  # type: ignore[no-untyped-def]
               efficiency, idle_a, mah_per_a, decay, ambient_c, heating_c_per_a,
               capacity_mah, empty_v, full_v, r_int_ohm):
    """One :meth:`PowerModel.step` on numbers: → (terminal voltage V, currents A,
    consumed mAh, temperatures °C, remaining %); max() of two floats as the conditional it
    is (NaN included). A pure function: the seam compiles it (:data:`EXAMPLE`)."""
    w1, w2, w3, w4 = omega_radps
    q1, q2, q3, q4 = consumed_mah
    t1, t2, t3, t4 = temps_c
    v_prev = voltage_v
    if v_prev < 1.0:
        v_prev = 1.0                                   # max(voltage_v, 1.0)
    kq_per_w = torque_coeff / (efficiency * v_prev)     # A per (rad/s)^3
    i1 = kq_per_w * w1 * w1 * abs(w1) + (idle_a if w1 > 0.0 else 0.0)
    i2 = kq_per_w * w2 * w2 * abs(w2) + (idle_a if w2 > 0.0 else 0.0)
    i3 = kq_per_w * w3 * w3 * abs(w3) + (idle_a if w3 > 0.0 else 0.0)
    i4 = kq_per_w * w4 * w4 * abs(w4) + (idle_a if w4 > 0.0 else 0.0)
    q1 += i1 * mah_per_a
    q2 += i2 * mah_per_a
    q3 += i3 * mah_per_a
    q4 += i4 * mah_per_a
    s1 = ambient_c + heating_c_per_a * i1
    s2 = ambient_c + heating_c_per_a * i2
    s3 = ambient_c + heating_c_per_a * i3
    s4 = ambient_c + heating_c_per_a * i4
    u1 = s1 + (t1 - s1) * decay
    u2 = s2 + (t2 - s2) * decay
    u3 = s3 + (t3 - s3) * decay
    u4 = s4 + (t4 - s4) * decay
    total_a = i1 + i2 + i3 + i4
    soc = 1.0 - (q1 + q2 + q3 + q4) / capacity_mah
    soc = soc if soc > 0.0 else 0.0                     # max(0.0, soc)
    v_oc = empty_v + (full_v - empty_v) * soc
    volts = v_oc - r_int_ohm * total_a
    volts = volts if volts > 0.0 else 0.0               # max(0.0, volts)
    return (volts, (i1, i2, i3, i4), (q1, q2, q3, q4), (u1, u2, u3, u4), 100.0 * soc)


_native: dict[str, Any] = {"core": None}


#: Arguments shaped as :meth:`PowerModel.step` passes them (what the seam lowers for).
EXAMPLE = ((0.0,) * 4, (0.0,) * 4, (0.0,) * 4) + (0.0,) * 12


def _load_native() -> None:
    """The compiled :func:`power_step`, now if built (or ``TFL_MAV_NATIVE=sync``), else when
    a background build completes; ``off``: never."""
    from tfl_mav.accel import native
    def ready(core: Any) -> None:
        _native["core"] = core

    core = native.obtain_function(power_step, EXAMPLE, ready)
    if core is not None:
        ready(core)


_load_native()
