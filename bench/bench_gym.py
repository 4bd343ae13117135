"""Steps per second of the Gymnasium environment (tfl_mav.gym), single and vectorised.

    python bench/bench_gym.py [--seconds 3] [--envs 2,4] [--json out.json]

Rows: one environment in this process (``gym.make``, with gymnasium's default wrappers),
as four rotor commands and as a residual on each base; the cost of a ``reset``; and
``AsyncVectorEnv`` with N environments in subprocesses (env-steps per second over all of
them). For scale, the offline runner's ticks per second for the same flight
(``Environment.fly``): the environment's overhead is what a step adds to a tick.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any

import gymnasium as gym
import numpy as np

import tfl_mav.gym  # noqa: F401  (registers TflMav-v0)
from tfl_mav.api import Environment
from tfl_mav.controller.software import load_flight_software


def _single(base: str | None, seconds: float) -> dict[str, Any]:
    env = gym.make("TflMav-v0", base=base)
    rng = np.random.default_rng(0)
    actions = (rng.uniform(-0.05, 0.05, (1000, 4)) if base else
               np.full((1000, 4), 2 * (1.1 * 9.81 / 4) / 8.0 - 1)).astype(np.float32)
    env.reset(seed=0, options={"attack": "none"})
    steps, resets = 0, 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for a in actions:
            _, _, term, trunc, _ = env.step(a)
            steps += 1
            if term or trunc:
                env.reset()
                resets += 1
    wall = time.perf_counter() - t0
    n = 20
    t1 = time.perf_counter()
    for i in range(n):
        env.reset(seed=i)
    reset_ms = (time.perf_counter() - t1) / n * 1e3
    env.close()
    return {"mode": f"single, {'residual on ' + base if base else 'rotor commands'}",
            "steps_per_s": steps / wall, "reset_ms": reset_ms, "episodes_reset": resets}


def _vector(n_envs: int, base: str | None, seconds: float) -> dict[str, Any]:
    envs = gym.vector.AsyncVectorEnv([lambda: gym.make("TflMav-v0", base=base)] * n_envs)
    try:
        envs.reset(seed=list(range(n_envs)), options={"attack": "none"})
        act = np.full((n_envs, 4), 0.0 if base else 2 * (1.1 * 9.81 / 4) / 8.0 - 1,
                      np.float32)
        steps = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            for _ in range(200):
                envs.step(act)           # autoreset: an ended episode restarts by itself
            steps += 200 * n_envs
        wall = time.perf_counter() - t0
    finally:
        envs.close()
    return {"mode": f"AsyncVectorEnv x{n_envs}, "
                    f"{'residual on ' + base if base else 'rotor commands'}",
            "steps_per_s": steps / wall, "reset_ms": float("nan"), "episodes_reset": 0}


def _offline(base: str | None, seconds: float) -> dict[str, Any]:
    software = None if base in (None, "tfl") else load_flight_software(base)[1]
    env = Environment("paper", software, settings=["attack.rotor=0"])
    t0 = time.perf_counter()
    ticks = 0
    while time.perf_counter() - t0 < seconds:
        ticks += len(env.fly(5.0).t_s)
    return {"mode": f"offline runner (Environment.fly), {base or 'tfl'}",
            "steps_per_s": ticks / (time.perf_counter() - t0), "reset_ms": float("nan"),
            "episodes_reset": 0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="wall seconds per row")
    ap.add_argument("--envs", default="2,4", help="vectorised sizes (comma-separated)")
    ap.add_argument("--json", metavar="FILE", help="write the rows as JSON")
    args = ap.parse_args()
    rows = [_single(None, args.seconds), _single("tfl", args.seconds),
            _single("se3", args.seconds), _single("cascade", args.seconds),
            _offline("tfl", args.seconds), _offline("se3", args.seconds)]
    for n in (int(x) for x in args.envs.split(",")):
        rows += [_vector(n, None, args.seconds), _vector(n, "tfl", args.seconds)]
    print(f"tfl_mav.gym on {os.cpu_count()} cores (paper scenario, no attack, 1 kHz steps)")
    print(f"{'mode':<52} {'steps/s':>10} {'reset ms':>9}")
    for r in rows:
        reset = f"{r['reset_ms']:.2f}" if np.isfinite(r["reset_ms"]) else "-"
        print(f"{r['mode']:<52} {r['steps_per_s']:>10.0f} {reset:>9}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
