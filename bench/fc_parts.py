"""The flight computer's step split into its parts by replaying a flight (bench_controller).

:func:`flight_computer_parts` — the detector, the TFL law, the safe law and the flight
computer's own work, mean CPU µs per tick of an offline flight, without a timer inside the
tick for the own work.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from harness.offline import fly_offline
from tfl_mav.control.detector import AttackDetector
from tfl_mav.control.law import TFLController
from tfl_mav.control.recovery import RecoveryLaw
from tfl_mav.flight_computer import FlightComputer
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
    around nothing."""
    parts = [(AttackDetector, "detector"), (TFLController, "TFL law"),
             (RecoveryLaw, "safe law")]
    saved = [(owner, owner.update) for owner, _ in parts]
    outs: dict[str, list[Any]] = {label: [] for _, label in parts}
    inputs: list[tuple[Any, ...]] = []
    step = FlightComputer.step

    def recording(owner: Any, fn: Callable[..., Any], label: str) -> Callable[..., Any]:
        def rec(*a: Any, **k: Any) -> Any:
            out = fn(*a, **k)
            outs[label].append(out)
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

    def replay(stubbed: bool, timed: str | None = None) -> float:
        try:
            if stubbed:
                for owner, label in parts:
                    it = iter(outs[label])
                    owner.update = (lambda self, *a, _it=it, **k: next(_it))  # type: ignore
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
    n = len(inputs)
    res = {"step": min(replay(False) for _ in range(rounds)),
           "own": min(replay(True) for _ in range(rounds))}
    for _, label in parts:
        res[label] = max(min(replay(False, label) for _ in range(rounds))
                         - min(bias) * len(outs[label]), 0.0)
    return {k: 1e6 * v / n for k, v in res.items()}
