"""The report figures a reader of the paper would recognise (PNG, matplotlib Agg)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from tfl_mav.flightlog.flight import FlightLog
from tfl_mav.flightlog.metrics import DEFAULT_BOUND_M

__all__ = ["write_report"]


MAX_POINTS = 20000
"""Most points one plotted line gets. A 20-minute flight has 1.2 M samples a series, a
figure ~800 pixels across: plotting them all made matplotlib hold ~0.7 GB. A longer series
is thinned to the minimum and maximum of each of ``MAX_POINTS / 2`` equal runs of samples,
so every spike and the envelope still show."""


def _thin(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) with at most ~:data:`MAX_POINTS` points: each run's min and max of y (NaN
    where a run has no finite value), in order; unchanged when short enough."""
    n = len(y)
    if n <= MAX_POINTS:
        return x, y
    runs = MAX_POINTS // 2
    size = -(-n // runs)
    m = n // size
    body = y[:m * size].reshape(m, size)
    finite = np.isfinite(body)
    lo = np.argmin(np.where(finite, body, np.inf), axis=1)
    hi = np.argmax(np.where(finite, body, -np.inf), axis=1)
    base = np.arange(m) * size
    idx = np.unique(np.concatenate((base + lo, base + hi, np.arange(m * size, n))))
    return x[idx], y[idx]


def _stride(a: np.ndarray) -> np.ndarray:
    """Every k-th row of ``a`` (and the last), at most ~:data:`MAX_POINTS` rows."""
    k = -(-len(a) // MAX_POINTS)
    return a if k <= 1 else np.concatenate((a[::k], a[-1:]))


def _mark_attack(ax, log: FlightLog) -> None:
    if np.isfinite(log.attack_start_s):
        ax.axvline(log.attack_start_s, color="tab:red", ls=":", lw=1, label="attack start")


def write_report(log: FlightLog, out_dir: Path, title: str = "") -> list[Path]:
    """Write the six report figures into ``out_dir``; returns the paths written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    t = log["t_s"]
    files: list[Path] = []
    suffix = f" — {title}" if title else ""
    if log.crashed:
        suffix += " (crashed)"

    def save(fig, name: str) -> None:
        path = out_dir / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)

    # 1. 3-D path and trajectory.
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    if log.path_points_m is not None:
        pp = log.path_points_m
        ax.plot(pp[:, 0], pp[:, 1], pp[:, 2], "k--", lw=1, label="path γ")
    pos = log["position_m"]
    if len(pos):
        p3 = _stride(pos)
        ax.plot(p3[:, 0], p3[:, 1], p3[:, 2], color="tab:blue", lw=1.2, label="vehicle")
        ax.scatter(*pos[0], color="tab:green", s=20, label="start")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m, up)")
    ax.set_title("Path following" + suffix)
    ax.legend(loc="upper left")
    save(fig, "path_3d.png")

    # 2. Path distance, log scale.
    fig, ax = plt.subplots(figsize=(7, 3.5))
    d = np.maximum(log["path_distance_m"], 1e-12)
    ax.semilogy(*_thin(t, d), color="tab:blue")
    _mark_attack(ax, log)
    ax.axhline(DEFAULT_BOUND_M, color="tab:green", ls="--", lw=1,
               label=f"convergence bound {DEFAULT_BOUND_M:g} m")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("distance to path ‖y‖_γ (m)")
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title("Distance to the path γ, ‖y‖_γ" + suffix)
    ax.legend(loc="upper right", fontsize=8)
    save(fig, "path_distance.png")

    # 3. Attack signal: applied and estimated.
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(*_thin(t, log["attack_true_n"]), label="A(t, x_q) applied", color="tab:red")
    est = log["attack_estimate_n"]
    if np.any(np.isfinite(est)):
        ax.plot(*_thin(t, est), "--", label="estimate from rpm", color="k", lw=0.8)
    ax.axhline(log.thrust_max_n, color="gray", ls=":", lw=1,
               label=f"rotor limit f_max = {log.thrust_max_n:g} N")
    _mark_attack(ax, log)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("thrust (N)")
    ax.set_title((f"Attack on rotor {log.attack_rotor}" if log.attack_rotor
                  else "No attack") + suffix)
    ax.legend()
    save(fig, "attack.png")

    # 4. Rotor thrusts with their limits: one panel a rotor (shared axes), so a rotor that
    # flies the same thrust as its opposite (f1 = f3 and f2 = f4 in a symmetric flight) is
    # still seen; the attacked rotor in red, with the attacker's thrust over it.
    fig, axes = plt.subplots(2, 2, figsize=(8, 5), sharex=True, sharey=True)
    ft = log["thrust_true_n"]
    attacked = log.attack_rotor
    for i, ax in enumerate(axes.flat):
        hit = i + 1 == attacked
        if len(ft):
            ax.plot(*_thin(t, ft[:, i]), lw=1.2, color="tab:red" if hit else "tab:blue",
                    label=f"f{i + 1} true")
        if hit and len(log["attack_true_n"]):
            ax.plot(*_thin(t, log["attack_true_n"]), "k--", lw=0.8,
                    label="attacker's A(t, x_q)")
        ax.axhline(0.0, color="gray", ls=":", lw=1)
        ax.axhline(log.thrust_max_n, color="gray", ls=":", lw=1)
        _mark_attack(ax, log)
        ax.set_title(f"rotor {i + 1}" + (" (attacked)" if hit else ""), fontsize=9,
                     color="tab:red" if hit else "black")
        ax.grid(True, alpha=0.3)
        if hit:
            ax.legend(fontsize=7, loc="upper right")
    for ax in axes[1]:
        ax.set_xlabel("t (s)")
    for ax in axes[:, 0]:
        ax.set_ylabel("thrust f_i (N)")
    fig.suptitle("Rotor thrusts f1-f4 (limits 0 and f_max dotted)"
                 + (f", rotor {attacked} attacked" if attacked else "") + suffix, fontsize=10)
    save(fig, "rotor_thrusts.png")

    # 5. Total thrust and torques.
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    a1.plot(*_thin(t, log["uf_n"]), color="tab:blue")
    a1.set_ylabel("total thrust u_f (N)")
    tq = log["torque_nm"]
    for i, name in enumerate(("τ_p", "τ_q", "τ_r")):
        if len(tq):
            a2.plot(*_thin(t, tq[:, i]), lw=0.9, label=name)
    a2.set_ylabel("torque (N m)")
    a2.set_xlabel("t (s)")
    a2.legend()
    a1.set_title("Total thrust u_f and body torques τ_p, τ_q, τ_r (eq. (4))" + suffix)
    save(fig, "thrust_torques.png")

    # 6. Linear and angular velocities.
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    vel = log["velocity_mps"]
    rates = log["body_rates_radps"]
    for i, name in enumerate(("v_x", "v_y", "v_z")):
        if len(vel):
            a1.plot(*_thin(t, vel[:, i]), lw=0.9, label=name)
    a1.set_ylabel("velocity, paper frame (m/s)")
    a1.legend()
    for i, name in enumerate(("p", "q", "r")):
        if len(rates):
            a2.plot(*_thin(t, rates[:, i]), lw=0.9, label=name)
    a2.set_ylabel("body rates p, q, r (rad/s)")
    a2.set_xlabel("t (s)")
    a2.legend()
    a1.set_title("Linear velocity and body rates" + suffix)
    save(fig, "velocities.png")
    return files
