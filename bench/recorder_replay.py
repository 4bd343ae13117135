"""A recorder child's work per tick, measured in-process on a real flight's hand-off batches.

Why: in the full lockstep loop the two recorder children (``RecorderProcess``) share the
2 cores with the serial sim ↔ daemon chain; their CPU per tick is what they take from it.
``/proc`` totals (``bench/bench_lockstep.py``) say how much, not where; a profile inside a
niced child on a shared machine is noisy. Here:

1. **capture**: a lockstep ``tfl-mav sim --mcap`` + ``tfl-mav fly --mcap`` flight whose two
   ``RecorderProcess`` parents also keep every pickled batch they send their child (a
   wrapper patches ``RecorderProcess`` in those processes only; nothing else changes);
2. **replay**: each side's batches fed to the child's own batch handler
   (:func:`tfl_mav.flightlog.recorder_process.handle_batch`: unpickle, decode, encode,
   write) into a real MCAP file, timed with the process CPU clock, per tick (a tick = one
   truth call on the sim side, one controller record on the daemon side); optionally under
   cProfile, split by :func:`profiling.categorize`'s recorder categories.

Usage: ``python bench/recorder_replay.py [--ticks N] [--repeats R] [--capture DIR]
[--replay DIR] [--profile] [--compression zstd|lz4|none]``.
"""

from __future__ import annotations

import argparse
import os
import pickle
import re
import runpy
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(BENCH))

_LISTEN_RE = re.compile(r"listening on ([\d.]+):(\d+)")


def _wrap(out_dir: str, module: str, args: list[str]) -> None:
    """Run ``python -m module args`` with every RecorderProcess keeping its sent batches
    (written to ``out_dir/<mcap name>.batches`` when it closes)."""
    from tfl_mav.flightlog import recorder_process as rp

    init, close = rp.RecorderProcess.__init__, rp.RecorderProcess.close

    def patched_init(self: Any, path: Any, **kw: Any) -> None:
        init(self, path, **kw)
        sent: list[bytes] = []
        send = self._conn.send_bytes
        self._captured = sent
        self._conn.send_bytes = lambda b: (sent.append(bytes(b)), send(b))[1]

    def patched_close(self: Any) -> None:
        close(self)
        name = Path(self.file_path).name if self.file_path else "live"
        Path(out_dir, name + ".batches").write_bytes(pickle.dumps(self._captured))

    rp.RecorderProcess.__init__ = patched_init     # type: ignore[method-assign]
    rp.RecorderProcess.close = patched_close       # type: ignore[method-assign]
    sys.argv = [module, *args]
    runpy.run_module(module, run_name="__main__", alter_sys=True)


def capture(n_ticks: int, out_dir: Path, scenario: str = "paper") -> None:
    """One lockstep flight (sim + fly, both ``--mcap``) whose batches land in ``out_dir``."""
    wrap = [sys.executable, __file__, "--wrap", str(out_dir), "tools.cli"]
    dur = f"{n_ticks / 1000.0:g}"
    sim = subprocess.Popen([*wrap, "sim", scenario, "--listen", "127.0.0.1:0", "--duration",
                            dur, "--mcap", str(out_dir / "run.mcap")],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        assert sim.stdout is not None
        m = _LISTEN_RE.search(sim.stdout.readline())
        if m is None:
            raise RuntimeError(f"sim did not start: {sim.communicate(timeout=20)}")
        subprocess.run([*wrap, "fly", scenario, "--vehicle", f"{m.group(1)}:{m.group(2)}",
                        "--duration", dur, "--mcap", str(out_dir / "ctl.mcap"), "--quiet"],
                       check=True, cwd=REPO, stdout=subprocess.DEVNULL)
        sim.communicate(timeout=60)
    finally:
        if sim.poll() is None:
            sim.kill()


def replay(batches_file: Path, out: Path, kwargs: dict[str, Any],
           profile: Path | None = None) -> dict[str, float]:
    """CPU µs per tick of the child's batch handler over one side's captured batches."""
    from tfl_mav.flightlog import recorder_process as rp
    from tfl_mav.flightlog.recorder import Recorder

    batches: list[bytes] = pickle.loads(batches_file.read_bytes())
    ticks = 0
    for b in batches:
        for item in pickle.loads(b):
            ticks += item[0] in (rp._TRUTH, rp._CONTROLLER)
    now = [0.0]
    rec = Recorder(out, clock=lambda: now[0], **kwargs)
    handle = rp.handle_batch
    prof = None
    if profile is not None:
        import cProfile

        prof = cProfile.Profile(time.process_time)
        prof.enable()
    t0 = time.process_time()
    for b in batches:
        handle(rec, b, now)
    rec.close()
    cpu = time.process_time() - t0
    if prof is not None:
        prof.disable()
        prof.dump_stats(str(profile))
    return {"ticks": ticks, "cpu_us_per_tick": cpu / max(1, ticks) * 1e6,
            "bytes": out.stat().st_size}


def _side_kwargs(side: str) -> dict[str, Any]:
    """The child's Recorder keywords as ``tfl-mav sim``/``fly`` give them (drawing only)."""
    from tfl_mav.airframe import rotor_xy_m
    from tfl_mav.daemon import TICK_FIELDS, TICK_SCHEMA
    from tfl_mav.scenario import load_scenario

    v = load_scenario("paper").vehicle
    kw: dict[str, Any] = {"rotor_xy_m": rotor_xy_m(v), "thrust_max_n": v.thrust_max_n}
    if side == "ctl":
        kw.update(controller_fields=TICK_FIELDS, controller_schema=TICK_SCHEMA)
    return kw


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--wrap":
        _wrap(sys.argv[2], sys.argv[3], sys.argv[4:])
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--capture", metavar="DIR", help="capture into DIR (kept) and replay")
    ap.add_argument("--replay", metavar="DIR", help="replay an earlier capture, no flight")
    ap.add_argument("--profile", action="store_true", help="also a profiled replay, by piece")
    ap.add_argument("--compression", choices=["zstd", "lz4", "none"], default=None)
    args = ap.parse_args()
    tmp = tempfile.TemporaryDirectory()
    src = Path(args.replay or args.capture or tmp.name)
    if not args.replay:
        src.mkdir(parents=True, exist_ok=True)
        capture(args.ticks, src)
    print(f"load {os.getloadavg()[0]:.2f}; batches from {src}")
    print(f"{'side':12s} {'ticks':>6s} {'µs/tick (min of runs)':>22s} {'MiB/min':>8s}")
    for side, label in (("run", "sim child"), ("ctl", "daemon child")):
        kw = _side_kwargs(side)
        if args.compression:
            kw["compression"] = args.compression
        runs = [replay(src / f"{side}.mcap.batches", Path(tmp.name) / f"{side}-r.mcap", kw)
                for _ in range(args.repeats)]
        best = min(r["cpu_us_per_tick"] for r in runs)
        mib = runs[0]["bytes"] / 2**20 * 60000 / max(1, runs[0]["ticks"])
        print(f"{label:12s} {runs[0]['ticks']:6d} {best:22.1f} {mib:8.2f}")
        if args.profile:
            from profiling import STARTUP, categorize

            prof = Path(tmp.name) / f"{side}.prof"
            r = replay(src / f"{side}.mcap.batches", Path(tmp.name) / f"{side}-p.mcap", kw,
                       profile=prof)
            shares = categorize(prof, "recorder")
            shares.pop(STARTUP)
            total = sum(shares.values()) or 1.0
            for k, v in shares.items():
                print(f"    {k:40s} {best * v / total:7.1f} µs")
            del r
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
