"""The spin law's flights (docs/relaxed-hover.md, "Flights"): a rotor pinned at 7 or 8 N
from t = 5 s on the paper path (rotor 2) and on the circle (rotor 3), with the controller's
model off by +2 %/+10 % or −2 %/−10 % (mass/inertia), with ideal rotors and with a 20 ms
motor lag. The flight computer flies until the take-over, the spin law after it
(tfl_mav.tools.harness.spin.fly_spin). Prints one line a flight and writes the figure:

    python bench/bench_spin.py [--duration 45] [--takeover 5.0] [--out docs/img]

(16 flights, ~2 min on one core.) ``--paper120`` flies instead the paper scenario's own
attack, 0.1 t + sin z, for 120 s with the spin law taking over at 40 s (where the signal
passes m g/2). ``--tick`` times one step of the law instead (no flight): the paper airframe,
rotor 2 pinned at 7.25 N (between two table rows), a tilted spinning body 0.1 m off the
target; the best of 5 runs of 3000 steps, in Python and compiled by the seam; and the same
for the coning hover's step (the fallback where no relaxed hover holds the weight) on the
same body, the thrust pinned at 7.5 N.
"""

from __future__ import annotations

import argparse
import itertools
import time
import timeit
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from tfl_mav.accel import native
from tfl_mav.control.spin import equilibrium, law
from tfl_mav.control.spin.cone import CONE_START, ConeInputs, cone_params, cone_step
from tfl_mav.control.spin.step import SpinInputs, spin_step
from tfl_mav.scenario import load_scenario
from tfl_mav.tools.harness.spin import fly_spin

ERRORS = {"+2%/+10%": (1.02, 1.1), "-2%/-10%": (0.98, 0.9)}


def case(name: str, signal: float, err: str, lag_s: float, duration: float,
         attack_start_s: float = 5.0):
    ms, js = ERRORS[err]
    sc = load_scenario(name).replace(**{
        "attack.signal": f"{signal:g}", "attack.start_s": attack_start_s,
        "controller.model_mass_scale": ms, "controller.model_inertia_scale": js,
        "vehicle.motor_time_constant_s": lag_s, "run.duration_s": duration})
    if name == "circle":
        sc = sc.replace(**{"attack.rotor": 3})
    return sc


def tick_us(number: int = 3000, repeat: int = 5, compiled: bool = False) -> float:
    """The spin law's step time (µs, best of ``repeat`` runs of ``number`` steps): the
    Python step, or (``compiled``) the seam's build of it, which the flight computer flies
    once built (:class:`~tfl_mav.control.spin.law.SpinLaw`)."""
    sc = load_scenario("paper")
    params = law.build(sc.vehicle, 2, sc.run.control_dt_s)
    eq = equilibrium.solve(equilibrium.airframe_from_scenario(sc.vehicle, 2), 7.25,
                           symmetric=True)
    assert eq is not None
    state = law.initial_state(params, eq.rates_radps, 7.25)
    inputs = SpinInputs((0.1, 0.0, 5.0), (0.1, 0.0, 0.0), (0.99, 0.1, 0.05, 0.0),
                        eq.rates_radps, 7.25, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0),
                        (0.0, 0.0, 0.0))
    step = spin_step
    if compiled:
        step = native.build_function(spin_step, (params, state, law.STEP_INPUTS_EXAMPLE))
        assert repr(step(params, state, inputs)) == repr(spin_step(params, state, inputs))
    best = min(timeit.repeat(lambda: step(params, state, inputs), number=number,
                             repeat=repeat))
    return best / number * 1e6


def cone_tick_us(number: int = 3000, repeat: int = 5, compiled: bool = False) -> float:
    """The coning hover's step time (µs, best of ``repeat`` runs of ``number`` steps), as
    :func:`tick_us`: the Python step, or the seam's build of it
    (:class:`~tfl_mav.control.spin.cone.ConeLaw`)."""
    sc = load_scenario("paper")
    params = cone_params(sc.vehicle, 2, sc.run.control_dt_s)
    inputs = ConeInputs((0.1, 0.0, 5.0), (0.1, 0.0, 0.0), (0.99, 0.1, 0.05, 0.0),
                        (1.0, 2.0, 10.0), 7.5, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0),
                        (0.0, 0.0, 0.0))
    step = cone_step
    if compiled:
        step = native.build_function(cone_step, (params, CONE_START, inputs))
        assert repr(step(params, CONE_START, inputs)) == repr(
            cone_step(params, CONE_START, inputs))
    best = min(timeit.repeat(lambda: step(params, CONE_START, inputs), number=number,
                             repeat=repeat))
    return best / number * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=45.0, help="flight length (s)")
    ap.add_argument("--takeover", type=float, default=5.0, help="spin law from (s)")
    ap.add_argument("--out", default="docs/img", help="directory of the figure")
    ap.add_argument("--paper120", action="store_true",
                    help="the paper attack 0.1 t + sin z over 120 s, take-over at 40 s")
    ap.add_argument("--tick", action="store_true",
                    help="time one step of the law (no flight)")
    args = ap.parse_args()
    if args.tick:
        print(f"spin_step: {tick_us():.1f} µs a tick in Python, "
              f"{tick_us(compiled=True):.2f} µs compiled (best of 5 × 3000, f_stuck 7.25 N)")
        print(f"cone_step: {cone_tick_us():.1f} µs a tick in Python, "
              f"{cone_tick_us(compiled=True):.2f} µs compiled (best of 5 × 3000, "
              "f_stuck 7.5 N)")
        return
    if args.paper120:
        sc = load_scenario("paper").replace(**{"run.duration_s": 120.0})
        t0 = time.perf_counter()
        f = fly_spin(sc, takeover_s=40.0)
        print(f"paper attack, 120 s, take-over 40 s: crashed={f.crashed} {f.crash_reason} "
              f"max distance after the take-over = {f.max_distance_after(40.0):.3f} m, "
              f"after 45 s = {f.max_distance_after(45.0):.3f} m, "
              f"Ω = {f.spin_radps:.1f} rad/s ({time.perf_counter() - t0:.1f} s wall)")
        return
    out = Path(args.out)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    print("path    rotor  f_stuck  model error  lag    crashed  max dist after take-over (m)"
          "  after +5 s  Ω (rad/s)  wall s")
    worst = 0.0
    for k, (name, signal, err, lag) in enumerate(itertools.product(
            ("paper", "circle"), (7.0, 8.0), ERRORS, (0.0, 0.02))):
        sc = case(name, signal, err, lag, args.duration)
        t0 = time.perf_counter()
        f = fly_spin(sc, takeover_s=args.takeover)
        wall = time.perf_counter() - t0
        d0 = f.max_distance_after(args.takeover)
        d5 = f.max_distance_after(args.takeover + 5.0)
        worst = max(worst, d0)
        print(f"{name:7s} {sc.attack.rotor:5d}  {signal:5.1f} N  {err:11s}  {lag * 1000:3.0f} ms"
              f"  {f.crashed!s:7s}  {d0:8.3f}                      {d5:8.3f}    "
              f"{f.spin_radps:7.1f}  {wall:5.1f}")
        ax = axes[0 if name == "paper" else 1]
        sel = f.t_s >= args.takeover - 1.0
        ax.semilogy(f.t_s[sel], np.maximum(f.distance_m[sel], 1e-4), lw=0.8,
                    label=f"{signal:g} N, {err}, {lag * 1000:.0f} ms", color=f"C{k % 8}")
    for ax, title in zip(axes, ("paper path, rotor 2 pinned", "circle, rotor 3 pinned"),
                         strict=True):
        ax.axhline(2.0, color="k", lw=0.8)
        ax.axvline(args.takeover, color="grey", lw=0.6, ls="--")
        ax.set_title(title)
        ax.set_xlabel("t (s)")
    axes[0].set_ylabel("distance to the path (m)")
    axes[1].legend(fontsize=7, ncol=2)
    fig.suptitle("Spin law from the take-over (dashed): the limit 2 m drawn")
    fig.tight_layout()
    fig.savefig(out / "relaxed-hover-flights.png", dpi=110)
    print(f"worst distance after the take-over: {worst:.3f} m; "
          f"figure {out}/relaxed-hover-flights.png")


if __name__ == "__main__":
    main()
