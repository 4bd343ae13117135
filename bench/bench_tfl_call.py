"""The TFL law's compiled tick, and the compiled step's call alone, in µs of thread CPU.

1. ``tick``: ``TFLController.update`` on the compiled core (``TFL_MAV_NATIVE=sync``), over
   1000 measured states of a closed-loop paper flight (ticks 2000-3000, rotor 2 attacked
   from 5 s: the attacked law), each round 20 passes over them. The law's state carries on
   from pass to pass, so the states are not its own next ones: most replayed ticks lose
   the projection and fall back (the figure printed; 75 % on the robust law), and the
   tick times the step, the fallback's words and the holder around them. ``--own``: each
   pass from a copy of the law as it was at tick 2000 (``copy.deepcopy``, not timed), so
   the states are its own next ones and no tick falls back (the attack estimate held at
   tick 2000's);
2. ``call``: the compiled step (``ctrl._core``) alone, 20 000 calls on one tick's
   arguments — the C function with its argument reading and its results (built and freed).

Each figure is the median over ``--rounds`` rounds (thread CPU time: a time slice another
process takes is not counted). With ``--ab-tree DIR`` the same runs alternate between
checkout ``DIR`` (its own ``.venv`` if it has one; its working directory, so its
``tfl_mav``) and this one, ``--pairs`` pairs, each a fresh interpreter; the table gives
the median of each tree's medians and the change. The script runs from any checkout with
``bench/bench_controller.py``'s ``_controller`` (07a6a37 on).

Usage: ``python bench/bench_tfl_call.py [--law robust|paper] [--own] [--rounds N]
[--ab-tree DIR [--pairs N]] [--json FILE]`` from the repository root.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


def flight_states(bc: Any, law_name: str) -> tuple[Any, Any, list[Any]]:
    """The paper flight's law (``controller.law`` = ``law_name``, compiled) flown 3000 ticks
    on the simulator of the working directory's checkout: (the law after them, a copy of it
    at tick 2000, the 1000 measured states from tick 2000 on). ``bc``: that checkout's
    bench_controller (its ``_controller``)."""
    from tfl_mav.model.state import State
    from tfl_mav.scenario import load_scenario
    try:
        from tfl_mav.sitl.simulator import Simulator
    except ImportError:                 # 07a6a37's layout
        from tfl_mav.sim.simulator import Simulator  # type: ignore[no-redef]

    sc = load_scenario("paper").replace(**{"controller.law": law_name})
    sim, ctrl = Simulator(sc), bc._controller(sc, True, "compiled")
    states = []
    at_2000 = None
    for k in range(3000):
        m = sim.measured
        if sim.attack.rotor:
            ctrl.set_attack(sim.attack.rotor, sim.attack.applied_n)
        st = State(m.position_m, m.velocity_mps, m.quaternion_wxyz, m.body_rates_radps)
        if k == 2000:
            at_2000 = copy.deepcopy(ctrl)
        out = ctrl.update(st)
        sim.set_command(out.rotor_thrust_n)
        sim.step_control_period()
        if k >= 2000:
            states.append(st)
    return ctrl, at_2000, states


def measure(law_name: str, rounds: int, own: bool = False) -> dict[str, float]:
    """Median µs per tick and per compiled call in the working directory's checkout; ``own``:
    each pass from a copy of the law as it was at tick 2000, so that the states are its
    own next ones (the attacked law's command, no fallback)."""
    os.environ["TFL_MAV_NATIVE"] = "sync"
    sys.path.insert(0, os.path.join(os.getcwd(), "bench"))
    import bench_controller as bc

    import tfl_mav
    print(f"bench_tfl_call: tfl_mav from {os.path.dirname(tfl_mav.__file__)}", file=sys.stderr)
    ctrl, at_2000, states = flight_states(bc, law_name)
    st = states[0]
    # Trees since the path kernels became an argument pass them last and take the start's
    # flags as booleans; older trees take floats and no kernels.
    kernels = (ctrl._kernels,) if hasattr(ctrl, "_kernels") else ()
    flags = (0.0, False, False) if kernels else (0.0, 0.0, 0.0)
    u = ctrl._inputs(st.position_m.tolist(), st.velocity_mps.tolist(),
                     st.quaternion_wxyz.tolist(), st.body_rates_radps.tolist(), *ctrl._free,
                     *flags)
    core, p, s0 = ctrl._core, ctrl.params, ctrl.state
    if core(p, s0, u, *kernels) is None:
        raise SystemExit("bench_tfl_call: the compiled step declined the inputs (not timed)")
    n = 20 * len(states)
    clock = time.thread_time
    ticks, calls = [], []
    for _ in range(rounds):
        spent = 0.0
        for _ in range(20):
            law = copy.deepcopy(at_2000) if own else ctrl
            t0 = clock()
            for st in states:
                law.update(st)
            spent += clock() - t0
        ticks.append(spent / n * 1e6)
        t0 = clock()
        for _ in range(n):
            core(p, s0, u, *kernels)
        calls.append((clock() - t0) / n * 1e6)
    # The replayed states are not the law's own next ones (each pass starts where the last
    # left the law's λ and observers): what share of the timed ticks fell back, and so ran
    # the fallback's words rather than the attacked law's command.
    law = copy.deepcopy(at_2000) if own else ctrl
    fallback = sum(bool(law.update(st).reason) for st in states) / len(states)
    return {"tick_us": statistics.median(ticks), "call_us": statistics.median(calls),
            "fallback_share": fallback}


def _run_in(tree: Path, law_name: str, rounds: int, own: bool) -> dict[str, float]:
    """:func:`measure` in a fresh interpreter of checkout ``tree`` (its directory first on
    the path: a worktree without a venv of its own runs its ``tfl_mav`` too)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        filter(None, (str(tree), os.environ.get("PYTHONPATH")))))
    python = tree / ".venv" / "bin" / "python"
    done = subprocess.run(
        [str(python) if python.exists() else sys.executable, str(Path(__file__).resolve()),
         "--law", law_name, "--rounds", str(rounds), "--child", *(["--own"] if own else [])],
        cwd=tree, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"bench_tfl_call: the run in {tree} failed: "
                         f"{(done.stderr.strip().splitlines() or [''])[-1]}")
    return json.loads(done.stdout.splitlines()[-1])  # type: ignore[no-any-return]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--law", choices=("robust", "paper"), default="robust")
    ap.add_argument("--own", action="store_true",
                    help="tick over the flight's own next states: each pass from a copy of "
                         "the law at tick 2000 (no fallback)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--ab-tree", metavar="DIR", type=Path,
                    help="alternate with checkout DIR (fresh interpreters)")
    ap.add_argument("--pairs", type=int, default=5, help="pairs for --ab-tree (default 5)")
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.pairs < 1:
        ap.error("--rounds and --pairs must be at least 1")
    if args.child:
        print(json.dumps(measure(args.law, args.rounds, args.own)))
        return 0
    if args.ab_tree is None:
        r: dict[str, Any] = measure(args.law, args.rounds, args.own)
        print(f"{args.law} law, compiled: tick {r['tick_us']:.2f} µs, the compiled call alone "
              f"{r['call_us']:.2f} µs (thread CPU, median of {args.rounds} rounds; "
              f"{100 * r['fallback_share']:.0f} % of the replayed ticks fall back)")
    else:
        if not (args.ab_tree / "tfl_mav").is_dir():
            ap.error(f"--ab-tree {args.ab_tree}: not a checkout (no tfl_mav/)")
        here = Path(__file__).resolve().parents[1]
        runs: dict[str, list[dict[str, float]]] = {"other": [], "this": []}
        for _ in range(args.pairs):
            runs["other"].append(_run_in(args.ab_tree, args.law, args.rounds, args.own))
            runs["this"].append(_run_in(here, args.law, args.rounds, args.own))
        r = {"law": args.law, "own": args.own, "rounds": args.rounds, "pairs": args.pairs,
             "other_tree": str(args.ab_tree), "runs": runs}
        print(f"{args.law} law, compiled, µs of thread CPU: {args.ab_tree} vs this checkout "
              f"({args.pairs} alternated pairs, median of {args.rounds} rounds each)")
        for key, label in (("tick_us", "tick (update)"), ("call_us", "the compiled call")):
            a = statistics.median(x[key] for x in runs["other"])
            b = statistics.median(x[key] for x in runs["this"])
            r[key] = {"other": a, "this": b}
            each = " ".join(f"{x[key]:.2f}/{y[key]:.2f}"
                            for x, y in zip(runs["other"], runs["this"], strict=True))
            print(f"  {label:18s} {a:6.2f} → {b:6.2f}  ({100 * (b / a - 1):+.1f} %)   "
                  f"pairs: {each}")
        share = [100 * x.get("fallback_share", math.nan) for x in runs["other"] + runs["this"]]
        print(f"  replayed ticks that fall back: {min(share):.0f}-{max(share):.0f} %")
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
