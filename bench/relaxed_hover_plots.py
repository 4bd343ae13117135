"""The figures of docs/relaxed-hover.md: the relaxed-hover equilibria of the paper airframe
with one rotor pinned at f_stuck, their existence under model errors, and the eigenvalues
of the linearised rotational dynamics (open loop, and the reduced attitude with the spin
law's LQR).

    python bench/relaxed_hover_plots.py [--out docs/img]

writes relaxed-hover-equilibria.png, relaxed-hover-existence.png and
relaxed-hover-eigenvalues.png, and prints the numbers the note quotes (~1 min).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from tfl_mav.control.safe.lqr import dlqr, zoh
from tfl_mav.control.spin import equilibrium as eqm
from tfl_mav.control.spin.law import LQR_Q, LQR_R
from tfl_mav.scenario import load_scenario

ERRORS = [(1.0, 1.0), (0.95, 0.8), (0.95, 1.2), (1.05, 0.8), (1.05, 1.2)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/img", help="directory of the figures")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    v = load_scenario("paper").vehicle
    nominal = eqm.airframe_from_scenario(v, 2)
    mg = nominal.mass_kg * nominal.gravity_mps2
    fs = np.linspace(0.5 * mg, nominal.thrust_max_n, 12)

    # 1. the equilibria over f_stuck, nominal and the corners of the model errors
    fig, ax = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    print("f_stuck N | f1 f2 f3 f4 N | Omega rad/s | axis n | cone deg | radius mm | margin N")
    for c, (ms, js) in enumerate(ERRORS):
        col = f"C{c}"
        a = eqm.airframe_from_scenario(v, 2, ms, js)
        eqs = [eqm.solve(a, float(f), symmetric=True) for f in fs]
        ok = [e for e in eqs if e is not None]
        lab = f"m x{ms:g}, J x{js:g}"
        x = [e.f_stuck_n for e in ok]
        ax[0, 0].plot(x, [abs(e.spin_radps) for e in ok], color=col, label=lab)
        ax[0, 1].plot(x, [math.degrees(e.cone_rad) for e in ok], color=col)
        ax[1, 0].plot(x, [e.thrusts_n[3] for e in ok], color=col)
        ax[1, 0].plot(x, [e.thrusts_n[0] for e in ok], "--", color=col)
        ax[1, 1].plot(x, [1000 * e.radius_m for e in ok], color=col)
        if (ms, js) == (1.0, 1.0):
            for e in ok:
                print(f"{e.f_stuck_n:5.2f} | {' '.join(f'{f:.2f}' for f in e.thrusts_n)} | "
                      f"{e.spin_radps:7.2f} | {' '.join(f'{c:+.3f}' for c in e.axis)} | "
                      f"{math.degrees(e.cone_rad):5.1f} | {1000 * e.radius_m:5.2f} | "
                      f"{e.margin_n:.2f}")
    ax[0, 0].set_ylabel("|Ω| (rad/s)")
    ax[0, 1].set_ylabel("cone angle θ (deg)")
    ax[1, 0].set_ylabel("rotor force (N): f4 solid, f1 = f3 dashed")
    ax[1, 1].set_ylabel("circle radius of the centre of mass (mm)")
    for a_ in ax[1]:
        a_.set_xlabel("f_stuck (N), rotor 2")
    ax[0, 0].legend(fontsize=7)
    fig.suptitle("Relaxed hover with rotor 2 pinned (paper airframe; widest-margin member)")
    fig.tight_layout()
    fig.savefig(out / "relaxed-hover-equilibria.png", dpi=110)

    # 2. existence: the mean vertical force range of all spins, against m g
    fig, ax = plt.subplots(figsize=(8, 5))
    print("\nexistence: f_stuck N | [W_min, W_max] N per airframe (m g in brackets)")
    for ms, js in ERRORS:
        a = eqm.airframe_from_scenario(v, 2, ms, js)
        rng = np.array([eqm.vertical_range(a, float(f), n=25) for f in fs])
        w = a.mass_kg * a.gravity_mps2
        line, = ax.plot(fs, rng[:, 1] / w, label=f"max, m x{ms:g}, J x{js:g}")
        ax.plot(fs, rng[:, 0] / w, "--", color=line.get_color())
        print(f"m x{ms:g} J x{js:g} (m g = {w:.2f}): " + ", ".join(
            f"{f:.1f}:[{lo:.1f},{hi:.1f}]" for f, (lo, hi) in zip(fs, rng, strict=True)))
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xlabel("f_stuck (N)")
    ax.set_ylabel("mean vertical force f_Σ n_z / m g")
    ax.set_title("An equilibrium exists where m g lies between the least (dashed) and\n"
                 "greatest (solid) mean vertical force of a spin, f1, f3, f4 in [0, f_max]")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "relaxed-hover-existence.png", dpi=110)

    # 3. eigenvalues: open loop (forces held, 5 states p, q, r, n_x, n_y) and the reduced
    # attitude (p, q, n_x, n_y) with the spin law's LQR (1 kHz zero-order hold)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5))
    print("\neigenvalues at 8 N (1/s): open loop, 5 states:")
    dt = 0.001
    for f in fs:
        e = eqm.solve(nominal, float(f), symmetric=True)
        col = plt.cm.viridis((f - fs[0]) / np.ptp(fs))
        lam = eqm.spin_eigenvalues(nominal, e)
        ax[0].plot(lam.real, lam.imag, "o", ms=4, color=col)
        a, b = eqm.reduced_model(nominal.inertia_kgm2, nominal.k_r, e.rates_radps, e.axis)
        ad, bd = zoh(a, b, dt)
        k = dlqr(ad, bd, np.diag(LQR_Q), np.diag(LQR_R))
        s_cl = np.log(np.linalg.eigvals(ad - bd @ k).astype(complex)) / dt
        ax[1].plot(s_cl.real, s_cl.imag, "o", ms=4, color=col)
        if f == fs[-1]:
            print(np.round(lam, 3))
            print("closed loop (reduced attitude, LQR):", np.round(s_cl, 2))
    ax[0].set_title("open loop (rotor forces held): nutation damped,\n"
                    "axis mode on the imaginary axis at ±iΩ")
    ax[1].set_title("reduced attitude with the spin law's LQR")
    for a_ in ax:
        a_.set_xlabel("Re λ (1/s)")
        a_.set_ylabel("Im λ (1/s)")
        a_.axvline(0.0, color="k", lw=0.6)
    sm = plt.cm.ScalarMappable(cmap="viridis", norm=plt.Normalize(fs[0], fs[-1]))
    fig.colorbar(sm, ax=ax, label="f_stuck (N)")
    fig.savefig(out / "relaxed-hover-eigenvalues.png", dpi=110)
    print(f"\nfigures in {out}/")


if __name__ == "__main__":
    main()
