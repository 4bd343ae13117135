"""The TFL holder's tick counted by callgrind: instructions, cache misses and branch misses a
tick, by function, deterministic where the shared machine's clocks are not.

Flies ``bench_tfl_call``'s paper flight (robust law, compiled, rotor 2 attacked from 5 s) to
tick 3000, then replays ticks 2000-3000 ``--passes`` times, each pass from a copy of the
law at tick 2000 (``bench_tfl_call --own``: no fallback; ``--replay``: the law carries on
instead, as ``bench_tfl_call``'s default does), with callgrind's instrumentation switched on
around the passes only (``callgrind_control``), so the counts are the ticks' and nothing
else's. Run it under valgrind from the checkout to count (any checkout from 07a6a37 on)::

    valgrind --tool=callgrind --instr-atstart=no [--cache-sim=yes --branch-sim=yes] \\
        --callgrind-out-file=OUT python bench/callgrind_tick.py [--passes 2] [--replay]
    callgrind_annotate OUT          # divide by 1000 × passes: per tick

Without valgrind it runs the same ticks, uncounted.
"""

from __future__ import annotations

import argparse
import copy
import os
import shutil
import subprocess
import sys


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--passes", type=int, default=2, help="passes of 1000 ticks counted")
    ap.add_argument("--replay", action="store_true",
                    help="the law carries on from pass to pass (most ticks fall back)")
    args = ap.parse_args(argv)
    os.environ["TFL_MAV_NATIVE"] = "sync"
    sys.path.insert(0, os.path.join(os.getcwd(), "bench"))
    import bench_controller as bc
    from bench_tfl_call import flight_states  # this script's own directory

    ctrl, at_2000, states = flight_states(bc, "robust")
    laws = [ctrl if args.replay else copy.deepcopy(at_2000) for _ in range(args.passes + 1)]
    for st in states:                   # one pass uncounted: everything warm
        laws[0].update(st)
    control = shutil.which("callgrind_control")
    pid = str(os.getpid())
    if control is not None:
        subprocess.run([control, "-i", "on", pid], capture_output=True, check=False)
    for law in laws[1:]:
        for st in states:
            law.update(st)
    if control is not None:
        subprocess.run([control, "-i", "off", pid], capture_output=True, check=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
