"""The flight computer's step split into its parts by replaying a flight (bench_controller).

:func:`flight_computer_parts` — the detector, the TFL law, the safe law and the flight
computer's own work, mean CPU µs per tick of an offline flight, without a timer inside the
tick for the own work.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from tfl_mav.control.detect.detector import AttackDetector
from tfl_mav.control.safe.recovery import RecoveryLaw
from tfl_mav.control.tfl.tfl_controller import TFLController
from tfl_mav.controller.flight_computer import FlightComputer
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import Scenario

__all__ = ["flight_computer_parts"]

_cpu = time.thread_time


def flight_computer_parts(sc: Scenario, duration_s: float | None,
                          rounds: int = 3) -> dict[str, float]:
    """Mean CPU µs per tick of :meth:`FlightComputer.step` over an offline flight (detector),
    split into the detector, the TFL law, the safe law and the flight computer's own work
    (which law flies, estimators it owns, command checks, the result record).

    The flight is flown once recording every step's inputs and the three parts' outputs;
    then fresh flight computers replay the inputs (a flight computer's outputs depend on its
    inputs alone), once as they are and once with each part replaced by its recorded
    output, so the own work is timed without any timer inside the tick (the best of
    ``rounds``). Each part is timed in a replay of its own, less what its timer reads
    around nothing.

    The detector twice more, without a timer: ``detector in situ``, the whole replay less
    one with the detector replaced by its recorded outputs (the stand-in's call added back):
    its cost among the laws, their caches and branch history; and ``detector alone``, a
    fresh detector replaying its own recorded inputs in a loop. (The laws cannot be left
    out one at a time: the flight computer hands the safe law's path parameter to the TFL
    law, so a recorded safe law would change the TFL law's inputs.) Measured: in situ
    ~2x alone; with the laws replaced as well it is the same as alone, so the difference
    is what the laws' code and data leave of the caches, not the detector's inputs."""
    parts = [(AttackDetector, "detector"), (TFLController, "TFL law"),
             (RecoveryLaw, "safe law")]
    saved = [(owner, owner.update) for owner, _ in parts]
    outs: dict[str, list[Any]] = {label: [] for _, label in parts}
    det_args: list[tuple[Any, ...]] = []
    inputs: list[tuple[Any, ...]] = []
    step = FlightComputer.step

    def recording(owner: Any, fn: Callable[..., Any], label: str) -> Callable[..., Any]:
        def rec(*a: Any, **k: Any) -> Any:
            out = fn(*a, **k)
            outs[label].append(out)
            if owner is AttackDetector:
                det_args.append(a[1:])
            return out
        return rec

    def rec_step(self: FlightComputer, *a: Any, **k: Any) -> Any:
        inputs.append((a, k))
        return step(self, *a, **k)

    try:
        for (owner, label), (_, fn) in zip(parts, saved, strict=True):
            owner.update = recording(owner, fn, label)  # type: ignore[method-assign]
        FlightComputer.step = rec_step  # type: ignore[method-assign]
        fly_offline(sc, attack_info="detector", duration_s=duration_s)
    finally:
        FlightComputer.step = step  # type: ignore[method-assign]
        for owner, fn in saved:
            owner.update = fn  # type: ignore[method-assign]

    def stand_in(label: str) -> Callable[..., Any]:
        """The part's recorded outputs, one a call, in order."""
        it = iter(outs[label])
        return lambda self, *a, _it=it, **k: next(_it)

    def replay(stubbed: bool, timed: str | None = None,
               only: str | None = None) -> float:
        try:
            if stubbed:
                for owner, label in parts:
                    if only is not None and label != only:
                        continue
                    owner.update = stand_in(label)  # type: ignore[method-assign]
            elif timed is not None:
                owner, fn = next((o, f) for (o, lb), (_, f) in zip(parts, saved, strict=True)
                                 if lb == timed)
                acc = [0.0]

                def t(*a: Any, _fn: Callable[..., Any] = fn, **k: Any) -> Any:
                    t0 = _cpu()
                    out = _fn(*a, **k)
                    acc[0] += _cpu() - t0
                    return out
                owner.update = t  # type: ignore[method-assign]
            fc = FlightComputer(sc, attack_info="detector", design_gains=False)
            st = fc.step
            t0 = _cpu()
            for a, k in inputs:
                st(*a, **k)
            total = _cpu() - t0
            return acc[0] if timed is not None else total
        finally:
            for owner, fn in saved:
                owner.update = fn  # type: ignore[method-assign]

    # What a part's timer reads around nothing (a clock read can be a system call in a VM):
    # taken off each timed call.
    bias = []
    for _ in range(rounds):
        t_sum = 0.0
        for _ in range(20000):
            t0 = _cpu()
            t_sum += _cpu() - t0
        bias.append(t_sum / 20000)

    def stand_in_calls() -> float:
        fn = stand_in("detector")
        t0 = _cpu()
        for _ in range(len(outs["detector"])):
            fn(None, 0.0, (), ())
        return _cpu() - t0

    def detector_alone() -> float:
        det = FlightComputer(sc, attack_info="detector", design_gains=False).detector
        assert det is not None
        up = det.update
        t0 = _cpu()
        for a in det_args:
            up(*a)
        return _cpu() - t0

    n = len(inputs)
    res = {"step": min(replay(False) for _ in range(rounds)),
           "own": min(replay(True) for _ in range(rounds))}
    # A difference of two long replays: taken in alternation (the load drifts), the best of
    # twice as many rounds.
    whole, without = [], []
    for _ in range(2 * rounds):
        whole.append(replay(False))
        without.append(replay(True, only="detector"))
    res["detector in situ"] = (min(whole) - min(without)
                               + min(stand_in_calls() for _ in range(rounds)))
    res["detector alone"] = min(detector_alone() for _ in range(rounds))
    for _, label in parts:
        res[label] = max(min(replay(False, label) for _ in range(rounds))
                         - min(bias) * len(outs[label]), 0.0)
    return {k: 1e6 * v / n for k, v in res.items()}
