"""Controller cost per evaluation (reference jets vs compiled path), its breakdown, and the
offline loop against a plain numpy RK4 physics-only loop — all in the same run.

    python bench/bench_controller.py [--scenario paper] [--ticks 4000] [--offline-s 20]
                                     [--numpy-s 5] [--repeats 3] [--offline-only [--fc-parts]]
                                     [--json FILE]

1. ``TFLController.update`` alone, median and p90 µs over a closed-loop flight (so the
   projection is warm-started as in real use), with the path evaluated by the reference jets
   (``compiled_path=False``: the jets evaluated generically) and on the path's kernels (the
   pure step, :mod:`tfl_mav.control.tfl.step`), in Python and compiled by the seam.
2. Where an update's time goes, per piece of the step (``observe``, ``project``,
   ``command``; exclusive µs per tick, by wrapping each with a timer: absolute numbers
   include the wrapper's cost, use the shares); compiled, the step is one call.
3. :meth:`FlightComputer.step` (detector + which law flies + the law + the command) timed
   tick by tick over a whole offline flight of the scenario (``fly_offline`` with the
   detector; the step wrapped from here, the runner untouched): median and p90 µs, by the
   mode that flew the tick (the paper flight spends ~a quarter of its ticks in the safe
   reduced-attitude law, ``LOST_ROTOR``); and the same step split into the detector, the
   TFL law, the safe law and the flight computer's own work, by replaying the flight's
   inputs (:func:`flight_computer_parts`).
4. The offline loop table: the offline loop (physics + law + detector at 1 kHz,
   ``tfl_mav.offline.fly_offline``, and the whole ``tfl-mav offline`` process) against a
   plain numpy RK4 loop of the same rigid body with the physics only, as the ratio of
   simulated seconds per CPU second (> 1: the full loop is faster), and where a tick of
   the loop goes (flight computer: law + detector; simulator: motors, attacker, RK4,
   sensors; the rest: hand-off, logging, crash check).

The offline rows fly ``--offline-s`` simulated seconds (default 20 s, the paper-length
flight ``tfl-mav demo`` flies: the attack and both dead-rotor stretches, when the safe law
takes over). That is the unit a researcher's sweep repeats, so the whole-process row charges
start-up (interpreter, imports, path code generation) once per flight as a sweep does; a
shorter run would mostly time imports and the costly first seconds, a longer one would hide
them. ``fly_offline`` flies the same flight in-process, so the two rows differ by start-up
alone. The numpy loop (``--numpy-s``, default 5 s) is a per-step rate, the same at any length.
Each round pairs the two rows with numpy runs right around them, and the table gives the
median ratio over ``--repeats`` rounds (this VM's speed drifts between runs).

Times are this thread's CPU time (``time.thread_time``), so being preempted on a shared
machine does not count; the loop ratios use CPU time as well (the CLI's from the child's
rusage). Absolute times still depend on the machine; the ratios are measured side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np
from fc_parts import flight_computer_parts

from tfl_mav import offline
from tfl_mav.control import actuators
from tfl_mav.control.path import compiled, tracker
from tfl_mav.control.path.compiled import compile_path
from tfl_mav.control.safe import recovery
from tfl_mav.control.tfl import step, tfl_controller
from tfl_mav.control.tfl.tfl_controller import TFLController
from tfl_mav.controller.flight_computer import FlightComputer
from tfl_mav.from_scenario import build_controller, model_params
from tfl_mav.model.state import State
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import Scenario, load_scenario
from tfl_mav.sitl.simulator import Simulator

_cpu = time.thread_time


def _controller(sc: Scenario, compiled_path: bool, core: str | None = None) -> TFLController:
    """The scenario's law: on the reference jets (``compiled_path=False``), else on the
    step in Python (``core="python"``) or compiled (``"compiled"``;
    None: whatever ``--core`` chose)."""
    saved = os.environ.get("TFL_MAV_NATIVE")
    if core is not None:
        os.environ["TFL_MAV_NATIVE"] = "sync" if core == "compiled" else "off"
    try:
        ctrl = build_controller(sc)
    finally:
        if saved is None:
            os.environ.pop("TFL_MAV_NATIVE", None)
        else:
            os.environ["TFL_MAV_NATIVE"] = saved
    if not compiled_path:
        ctrl.tracker, ctrl.path_eval = compiled.make_tracker(ctrl.tracker.path, False)
    elif core is not None and ctrl.core != core:
        raise SystemExit(f"bench_controller: the law's {core} core is not available "
                         f"(it flies {ctrl.core}); see the warning above")
    return ctrl


def time_law(sc: Scenario, ticks: int, compiled_path: bool, core: str | None = None,
             wrap_ctrl: Callable[[TFLController], None] | None = None) -> list[float]:
    """Seconds per ``update`` over a closed-loop flight of ``ticks`` control periods
    (``wrap_ctrl(ctrl)``: wraps the controller's pieces with timers before it flies)."""
    sim, ctrl = Simulator(sc), _controller(sc, compiled_path, core)
    if wrap_ctrl is not None:
        wrap_ctrl(ctrl)
    out_s = []
    for _ in range(ticks):
        m = sim.measured
        if sim.attack.rotor:
            ctrl.set_attack(sim.attack.rotor, sim.attack.applied_n)
        st = State(m.position_m, m.velocity_mps, m.quaternion_wxyz, m.body_rates_radps)
        t0 = _cpu()
        out = ctrl.update(st)
        out_s.append(_cpu() - t0)
        sim.set_command(out.rotor_thrust_n)
        sim.step_control_period()
    return out_s


# ----- breakdown ----------------------------------------------------------------------------
COMPILED = "the compiled step (one call)"
# The step's pieces (tfl_mav.control.tfl.step), wrapped where the flying step calls them: in
# the module, where tfl_step (and the reference tracker's tick) look them up.
PIECES = [("observe: R, axes, estimators, rows (1), (3), (9)", "observe"),
          ("project: closest point, π, α, Dφ (13)-(15)", "project"),
          ("command: (21), (3), allocation (4), (6), (9)", "command")]
STEPS: list[tuple[str, Any, str]] = [
    ("path: reference jets (8), (13)-(15)", tracker.PathTracker, "virtual_output"),
    ("lag inverse", actuators.MotorLagInverter, "reachable"),
    ("lag inverse", actuators.MotorLagInverter, "invert"),
    ("update: the rest (inputs, words, record)", tfl_controller.TFLController, "update"),
]
LABELS = [COMPILED, *(label for label, _ in PIECES), *(label for label, _, _ in STEPS)]


def breakdown(sc: Scenario, ticks: int, compiled_path: bool, core: str | None = None
              ) -> dict[str, float]:
    """Exclusive µs per tick of each step (wrapped with timers, restored afterwards).

    A wrapper costs its caller time that the wrapped step's own timer cannot see (the call
    into the wrapper, the timer reads, the bookkeeping): that overhead is measured on an
    empty function first and charged to no step, so a caller's exclusive time (e.g. "the
    rest" of ``update``) is not inflated by the number of steps it calls."""
    acc: dict[str, float] = defaultdict(float)
    stack: list[float] = []
    saved = []
    hidden = [0.0]      # per wrapped call: the wrapper's cost outside its own timer (s)

    def wrap(label: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*a: Any, **k: Any) -> Any:
            t0 = _cpu()
            stack.append(0.0)
            try:
                return fn(*a, **k)
            finally:
                el = _cpu() - t0
                acc[label] += el - stack.pop()
                if stack:
                    stack[-1] += el + hidden[0]
        return timed

    def noop() -> None:
        return None

    n_cal = 20000
    probe = wrap("calibration", noop)
    for _ in range(3):          # warm up, then take the cheapest of a few rounds
        t0 = _cpu()
        for _ in range(n_cal):
            noop()
        bare = _cpu() - t0
        acc["calibration"] = 0.0
        t0 = _cpu()
        for _ in range(n_cal):
            probe()
        outside = _cpu() - t0
        cost = max((outside - bare - acc["calibration"]) / n_cal, 0.0)
        hidden[0] = cost if hidden[0] == 0.0 else min(hidden[0], cost)
    del acc["calibration"]

    for label, owner, name in STEPS:
        fn = owner.__dict__.get(name)
        if fn is not None:
            saved.append((owner, name, fn))
            setattr(owner, name, wrap(label, fn))
    def wrap_ctrl(ctrl: TFLController) -> None:
        if ctrl._core is not None:
            ctrl._core = wrap(COMPILED, ctrl._core)
        ns = vars(step)
        for label, name in PIECES:
            saved.append((ns, name, ns[name]))
            ns[name] = wrap(label, ns[name])

    try:
        time_law(sc, ticks, compiled_path, core, wrap_ctrl=wrap_ctrl)
    finally:
        for owner, name, fn in reversed(saved):
            if isinstance(owner, dict):
                owner[name] = fn
            else:
                setattr(owner, name, fn)
    return {k: 1e6 * v / ticks for k, v in acc.items()}


# ----- the whole tick over a flight --------------------------------------------------------
def time_flight_computer(sc: Scenario, duration_s: float | None) -> dict[str, list[float]]:
    """Seconds per :meth:`FlightComputer.step` over an offline flight, keyed by the mode of
    the tick ("all" too). The method is wrapped on the class for the flight, then restored."""
    by_mode: dict[str, list[float]] = defaultdict(list)
    step = FlightComputer.step

    def timed(self: FlightComputer, *a: Any, **k: Any) -> Any:
        t0 = _cpu()
        res = step(self, *a, **k)
        el = _cpu() - t0
        by_mode[res.law.mode.name].append(el)
        by_mode["all"].append(el)
        return res

    FlightComputer.step = timed  # type: ignore[method-assign]
    try:
        fly_offline(sc, attack_info="detector", duration_s=duration_s)
    finally:
        FlightComputer.step = step  # type: ignore[method-assign]
    return by_mode


# ----- offline loop vs a plain numpy RK4 -----------------------------------------------------
def numpy_rk4_rtf(sc: Scenario, sim_s: float) -> float:
    """Simulated s per wall s of the rigid body (§III eq. (3)) integrated by RK4 with numpy
    arrays — the plain way to write the physics — at hover thrust, physics only (per CPU s)."""
    v = sc.vehicle
    m, g = v.mass_kg, 9.81
    J = np.array(v.inertia_kgm2)
    kt, kr = v.k_t, v.k_r
    wrench = np.array([m * g, 0.0, 0.0, 0.0])
    e3 = np.array([0.0, 0.0, 1.0])

    def f(x: np.ndarray) -> np.ndarray:
        vel, q, w = x[3:6], x[6:10], x[10:13]
        qw, qx, qy, qz = q
        b3 = np.array([2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx),
                       1 - 2 * (qx * qx + qy * qy)])
        acc = wrench[0] / m * b3 - g * e3 - kt / m * vel
        omega = np.array([0.0, *w])
        qdot = 0.5 * np.array([
            q[0] * omega[0] - q[1] * omega[1] - q[2] * omega[2] - q[3] * omega[3],
            q[0] * omega[1] + q[1] * omega[0] + q[2] * omega[3] - q[3] * omega[2],
            q[0] * omega[2] - q[1] * omega[3] + q[2] * omega[0] + q[3] * omega[1],
            q[0] * omega[3] + q[1] * omega[2] - q[2] * omega[1] + q[3] * omega[0]])
        wdot = (wrench[1:] - kr * w - np.cross(w, J * w)) / J
        return np.concatenate([vel, acc, qdot, wdot])

    h = sc.run.physics_dt_s
    n = round(sim_s / h)
    x = np.array([0.0, 0.0, 1.0, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0])
    t0 = _cpu()
    for _ in range(n):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[6:10] /= np.linalg.norm(x[6:10])
    return sim_s / (_cpu() - t0)


def offline_rtf(sc: Scenario, sim_s: float) -> float:
    """Simulated s per CPU s of ``fly_offline`` (physics + detector + law, in-process)."""
    t0 = _cpu()
    log = fly_offline(sc, attack_info="detector", duration_s=sim_s)
    wall = _cpu() - t0
    return float(log["t_s"][-1] + sc.run.control_dt_s) / wall


def offline_breakdown(sc: Scenario, sim_s: float) -> dict[str, float]:
    """CPU µs per tick of ``fly_offline`` by piece (timer wrappers on the flight computer's
    step, the simulator's tick, the log's building and the set-up, in a run of its own so
    they do not touch the RTF; what the two per-tick wrappers cost around nothing is
    measured and shown apart, not left in the loop's row)."""
    fc_label, sim_label = ("flight computer: law + detector",
                           "simulator: motors + attacker + RK4 + sensors")
    fill_label, setup_label = "the log built from the rows", "set-up: flight computer, sim"
    acc = dict.fromkeys((fc_label, sim_label, fill_label, setup_label), 0.0)

    def timed(label: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(*a: Any, **k: Any) -> Any:
            t0 = _cpu()
            try:
                return fn(*a, **k)
            finally:
                acc[label] += _cpu() - t0
        return wrapper

    saved = [(FlightComputer, "step", FlightComputer.step),
             (Simulator, "step_control_period", Simulator.step_control_period),
             (offline, "_fill", offline._fill),
             (FlightComputer, "__init__", FlightComputer.__init__),
             (Simulator, "__init__", Simulator.__init__)]
    for (owner, name, fn), label in zip(saved, (fc_label, sim_label, fill_label, setup_label,
                                                setup_label), strict=True):
        setattr(owner, name, timed(label, fn))
    try:
        t0 = _cpu()
        log = fly_offline(sc, attack_info="detector", duration_s=sim_s)
        total = _cpu() - t0
    finally:
        for owner, name, fn in saved:
            setattr(owner, name, fn)
    n = len(log["t_s"])
    out = {k: 1e6 * v / n for k, v in acc.items()}
    nothing = timed("nothing", lambda self: None)
    acc["nothing"] = 0.0
    t0 = _cpu()
    for _ in range(2 * n):
        nothing(None)
    out["the two timers around nothing"] = 1e6 * (_cpu() - t0) / n
    out["the loop: hand-off, log rows, crash check"] = 1e6 * total / n - sum(out.values())
    return out


def cli_rtf(scenario: str, sim_s: float) -> float:
    """Simulated s per CPU s of the whole ``tfl-mav offline`` process (start-up included)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-m", "tfl_mav.tools.cli", "offline", scenario, "--json",
                    "--attack-info", "detector", "--duration", str(sim_s)],
                   check=True, capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return sim_s / cpu


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--ticks", type=int, default=4000)
    ap.add_argument("--offline-s", type=float, default=20.0,
                    help="simulated s of the offline flights (default 20: paper length)")
    ap.add_argument("--numpy-s", type=float, default=5.0,
                    help="simulated s of the numpy RK4 baseline (default 5)")
    ap.add_argument("--repeats", type=int, default=3,
                    help="rounds of the offline rows, each paired with its own numpy RK4 "
                         "runs (default 3; the median ratio is reported)")
    ap.add_argument("--no-offline", action="store_true", help="skip the offline-loop table")
    ap.add_argument("--offline-only", action="store_true",
                    help="only the offline-loop table (skip the controller tables)")
    ap.add_argument("--fc-parts", action="store_true",
                    help="with --offline-only: the flight computer step's parts too")
    ap.add_argument("--flight-s", type=float, default=None,
                    help="simulated s of the flight-computer flight (default: the scenario's)")
    ap.add_argument("--no-flight", action="store_true",
                    help="skip the flight-computer-step table")
    ap.add_argument("--core", choices=("compiled", "python"), default="compiled",
                    help="the law's core for every table but the law's own (which shows "
                         "both): compiled to C (TFL_MAV_NATIVE=sync, the default) or the "
                         "generated Python (off)")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args(argv)
    # Subprocesses (tfl-mav offline) inherit it; the kernels are built (and cached) by the
    # first controller of each law, before anything is timed.
    os.environ["TFL_MAV_NATIVE"] = "sync" if args.core == "compiled" else "off"
    for law_name in ("robust", "paper"):
        build_controller(load_scenario(args.scenario).replace(
            **{"controller.law": law_name}))
    if args.repeats < 1:
        ap.error(f"--repeats must be at least 1, got {args.repeats}")
    sc0 = load_scenario(args.scenario)
    result: dict[str, Any] = {"scenario": args.scenario, "ticks": args.ticks}
    if args.offline_only:
        if args.fc_parts:
            _parts_table(sc0, args, result)
        return _offline_table(sc0, args, result)

    t0 = _cpu()
    ctl0 = build_controller(sc0)
    kernels = compile_path(ctl0.tracker.path)
    result["codegen_ms"] = {"path": 1e3 * kernels.build_s,
                            "controller_build": 1e3 * (_cpu() - t0)}
    mp = model_params(sc0)
    recovery.forget_gain_schedules()     # designed afresh, as a new process would
    t0 = _cpu()
    n_gains = len(recovery.gain_schedule(mp.inertia_kgm2, mp.k_r, sc0.run.control_dt_s))
    result["safe_law_gains"] = {"count": n_gains, "design_ms": 1e3 * (_cpu() - t0)}

    rows = []
    print("TFL law update, µs per tick: the reference jets, the step in Python, and compiled "
          "to C\n"
          f"{'law':8s} {'jets median':>11s} {'python median':>13s} {'C median':>9s} "
          f"{'speed-up':>8s} {'jets p90':>8s} {'python p90':>10s} {'C p90':>7s}")
    for law_name in ("robust", "paper"):
        sc = sc0.replace(**{"controller.law": law_name})
        ref = sorted(time_law(sc, args.ticks, False))
        py = sorted(time_law(sc, args.ticks, True, "python"))
        fast = sorted(time_law(sc, args.ticks, True, "compiled"))
        r = {"law": law_name, "jets_median_us": 1e6 * statistics.median(ref),
             "python_median_us": 1e6 * statistics.median(py),
             "compiled_median_us": 1e6 * statistics.median(fast),
             "jets_p90_us": 1e6 * ref[int(0.9 * len(ref))],
             "python_p90_us": 1e6 * py[int(0.9 * len(py))],
             "compiled_p90_us": 1e6 * fast[int(0.9 * len(fast))]}
        r["speedup"] = r["jets_median_us"] / r["compiled_median_us"]
        rows.append(r)
        print(f"{law_name:8s} {r['jets_median_us']:11.1f} {r['python_median_us']:13.1f} "
              f"{r['compiled_median_us']:9.1f} {r['speedup']:7.2f}x {r['jets_p90_us']:8.1f} "
              f"{r['python_p90_us']:10.1f} {r['compiled_p90_us']:7.1f}")
    result["controller"] = rows
    print(f"(path code generation at start-up: {result['codegen_ms']['path']:.1f} ms, the "
          f"controller {result['codegen_ms']['controller_build']:.1f} ms; the safe "
          f"law's {n_gains} LQR gains: {result['safe_law_gains']['design_ms']:.1f} ms)")

    print(f"\nbreakdown, robust law, exclusive µs per tick (the timers' own cost removed; the "
          f"compiled step is one call)\n{'step':40s} {'jets':>8s} {'python':>8s} {'C':>8s}")
    sc = sc0.replace(**{"controller.law": "robust"})
    n = max(500, args.ticks // 2)
    b_ref, b_py, b_fast = (breakdown(sc, n, False), breakdown(sc, n, True, "python"),
                           breakdown(sc, n, True, "compiled"))
    for label in dict.fromkeys(LABELS):
        print(f"{label:40s} {b_ref.get(label, 0.0):8.1f} {b_py.get(label, 0.0):8.1f} "
              f"{b_fast.get(label, 0.0):8.1f}")
    print(f"{'total':40s} {sum(b_ref.values()):8.1f} {sum(b_py.values()):8.1f} "
          f"{sum(b_fast.values()):8.1f}")
    result["breakdown_us"] = {"jets": b_ref, "python": b_py, "compiled": b_fast}

    if not args.no_flight:
        by_mode = time_flight_computer(sc0, args.flight_s)
        print(f"\nflight computer step over the {args.scenario} flight (detector), µs\n"
              f"{'mode':12s} {'ticks':>6s} {'median':>8s} {'p90':>8s}")
        fc_rows = {}
        for mode in ["all", *sorted(k for k in by_mode if k != "all")]:
            t = sorted(by_mode[mode])
            fc_rows[mode] = {"ticks": len(t), "median_us": 1e6 * statistics.median(t),
                             "p90_us": 1e6 * t[int(0.9 * len(t))]}
            r = fc_rows[mode]
            print(f"{mode:12s} {r['ticks']:6d} {r['median_us']:8.1f} {r['p90_us']:8.1f}")
        result["flight_computer_step"] = fc_rows
        _parts_table(sc0, args, result)

    if args.no_offline:
        _write(args.json, result)
        return 0
    return _offline_table(sc0, args, result)


def _parts_table(sc0: Scenario, args: argparse.Namespace, result: dict[str, Any]) -> None:
    parts = flight_computer_parts(sc0, args.flight_s)
    print("\nthe flight computer step, mean CPU µs per tick of the flight (replayed; own: the "
          "parts replaced by their recorded outputs)")
    rows = [(label, parts[label]) for label in ("detector", "TFL law", "safe law", "own")]
    rows += [("step (replayed whole)", parts["step"]),
             ("overhead: step − TFL law − safe law",
              parts["step"] - parts["TFL law"] - parts["safe law"]),
             ("detector in situ (no timer)", parts["detector in situ"]),
             ("detector alone (its inputs, in a loop)", parts["detector alone"])]
    for label, us in rows:
        print(f"  {label:40s} {us:7.1f}")
    result["flight_computer_parts_us"] = parts


def _write(path: str | None, result: dict[str, Any]) -> None:
    if path:
        with open(path, "w") as fh:
            json.dump(result, fh, indent=2)


def _offline_table(sc0: Scenario, args: argparse.Namespace, result: dict[str, Any]) -> int:
    """The offline loop (same-run ratios to a plain numpy RK4 loop) and the loop's pieces."""
    # Each measurement is paired with a numpy RK4 run right before and after it (this VM's
    # speed drifts up to ~2x between runs, less within a few seconds); the figure is the
    # median over --repeats rounds of the ratio to its own pair's mean.
    loop_ratios, cli_ratios, rk4s, offs, clis = [], [], [], [], []
    rk4_prev = numpy_rk4_rtf(sc0, args.numpy_s)
    for _ in range(args.repeats):
        off = offline_rtf(sc0, args.offline_s)
        rk4_mid = numpy_rk4_rtf(sc0, args.numpy_s)
        cli = cli_rtf(args.scenario, args.offline_s)
        rk4_next = numpy_rk4_rtf(sc0, args.numpy_s)
        loop_ratios.append(off / (0.5 * (rk4_prev + rk4_mid)))
        cli_ratios.append(cli / (0.5 * (rk4_mid + rk4_next)))
        rk4s += [rk4_prev, rk4_mid]
        offs.append(off)
        clis.append(cli)
        rk4_prev = rk4_next
    rk4s.append(rk4_prev)
    rk4, off, cli = (statistics.median(x) for x in (rk4s, offs, clis))
    loop_vs, cli_vs = statistics.median(loop_ratios), statistics.median(cli_ratios)
    pieces = offline_breakdown(sc0, args.offline_s)
    result["offline"] = {"numpy_rk4_rtf": rk4, "offline_loop_rtf": off,
                         "cli_process_rtf": cli, "loop_vs_numpy": loop_vs,
                         "cli_vs_numpy": cli_vs, "loop_vs_numpy_rounds": loop_ratios,
                         "cli_vs_numpy_rounds": cli_ratios, "repeats": args.repeats,
                         "offline_s": args.offline_s, "numpy_s": args.numpy_s,
                         "breakdown_us": pieces}

    def spread(r: list[float]) -> str:
        return f"{min(r):.2f}-{max(r):.2f}x" if len(r) > 1 else ""

    print(f"\n{'loop (simulated s per CPU s; medians of ' + str(args.repeats) + ' rounds)':52s} "
          f"{'RTF':>6s} {'vs numpy RK4':>12s} {'rounds':>11s}")
    print(f"{'plain numpy RK4, physics only (paired with each)':52s} {rk4:6.2f} "
          f"{1.0:11.2f}x")
    print(f"{f'fly_offline: physics + detector + law, {args.offline_s:g} s':52s} "
          f"{off:6.2f} {loop_vs:11.2f}x {spread(loop_ratios):>11s}")
    print(f"{f'tfl-mav offline, whole process, {args.offline_s:g} s flight':52s} {cli:6.2f} "
          f"{cli_vs:11.2f}x {spread(cli_ratios):>11s}")
    print("\nfly_offline per tick (CPU µs; the timers apart)")
    for label, us in pieces.items():
        print(f"  {label:50s} {us:7.1f}")
    print(f"  {'total':50s} {sum(pieces.values()):7.1f}")
    _write(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
