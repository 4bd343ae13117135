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

Same-run before/after: ``--tree DIR`` replays with the ``tfl_mav`` of another checkout
(e.g. the main branch, whose child has no ``handle_batch``: its old per-item dispatch is
used), so both trees chew the very same batches; ``--before DIR`` runs that tree in a
subprocess and prints both side by side, alternating runs.

Usage: ``python bench/recorder_replay.py [--ticks N] [--scenario S] [--repeats R] [--capture DIR]
[--replay DIR] [--profile] [--compression zstd|lz4|none] [--before DIR] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
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

REPO = Path(__file__).resolve().parents[1]    # the subprocesses' working directory

_LISTEN_RE = re.compile(r"listening on ([\d.]+):(\d+)")


def _wrap(out_dir: str, module: str, args: list[str]) -> None:
    """Run ``python -m module args`` with every RecorderProcess keeping its sent batches
    (written to ``out_dir/<mcap name>.batches`` when it closes)."""
    from tfl_mav.flightlog import recorder_process as rp

    init, close = rp.RecorderProcess.__init__, rp.RecorderProcess.close
    write = getattr(rp, "_write_message", None)    # the pipe's writer (else send_bytes)
    by_fd: dict[int, list[bytes]] = {}

    def patched_init(self: Any, path: Any, **kw: Any) -> None:
        init(self, path, **kw)
        sent: list[bytes] = []
        self._captured = sent
        if write is not None:
            by_fd[self._conn.fileno()] = sent
        else:
            send = self._conn.send_bytes
            self._conn.send_bytes = lambda b: (sent.append(bytes(b)), send(b))[1]

    def patched_write(fd: int, data: bytes, waited: Any) -> None:
        sent = by_fd.get(fd)
        if sent is not None:
            sent.append(bytes(data))
        write(fd, data, waited)   # type: ignore[misc]

    if write is not None:
        rp._write_message = patched_write

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
    # the command line's module in checkout REPO (tfl_mav/cli/ before the tools moved)
    cli = "tfl_mav.cli" if (REPO / "tfl_mav" / "cli").is_dir() else "tfl_mav.tools.cli"
    wrap = [sys.executable, __file__, "--wrap", str(out_dir), f"{cli}.main"]
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


def _old_handle_batch(rec: Any, data: bytes, now: list[float]) -> bool:
    """The child's per-item dispatch before ``handle_batch`` existed (older trees)."""
    from tfl_mav.flightlog import recorder_process as rp

    for item in pickle.loads(data):
        op, now[0] = item[0], item[1]
        if op == rp._FRAME:
            rec.on_frame(item[2], item[3], True if item[4] else None, item[1])
        elif op == rp._TRUTH:
            rec.truth(*item[2])
        elif op == rp._CONTROLLER:
            rec.controller(item[2], item[3])
        elif op == rp._LOG:
            rec.log(item[2], item[3], item[4], source=item[5])
        elif op == rp._SIM_TIME:
            rec.set_sim_time(item[2])
        elif op == rp._PATH:
            rec.path(item[2])
        elif op == rp._METADATA:
            rec.metadata(item[2], item[3])
        elif op == rp._CLOSE:
            return False
    return True


def replay(batches_file: Path, out: Path, kwargs: dict[str, Any],
           profile: Path | None = None, ticks: int = 0) -> dict[str, float]:
    """CPU µs per tick of the child's batch handler over one side's captured batches
    (``ticks``: per how many ticks; 0: count them, truth or controller calls)."""
    from tfl_mav.flightlog import recorder_process as rp
    from tfl_mav.flightlog.recorder import Recorder

    batches: list[bytes] = pickle.loads(batches_file.read_bytes())
    if not ticks:
        for b in batches:
            for item in pickle.loads(b):
                ticks += item[0] in (rp._TRUTH, rp._CONTROLLER)
    now = [0.0]
    rec = Recorder(out, clock=lambda: now[0], **kwargs)
    handle = getattr(rp, "handle_batch", _old_handle_batch)
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
    from tfl_mav.controller.daemon import TICK_FIELDS, TICK_SCHEMA
    from tfl_mav.model.airframe import rotor_xy_m
    from tfl_mav.scenario import load_scenario

    v = load_scenario("paper").vehicle
    kw: dict[str, Any] = {"rotor_xy_m": rotor_xy_m(v), "thrust_max_n": v.thrust_max_n}
    if side == "ctl":
        kw.update(controller_fields=TICK_FIELDS, controller_schema=TICK_SCHEMA)
    return kw


# where a child's CPU goes, unprofiled: the same replay with only one kind of call kept
# (plus the set-up calls: metadata, path), each with its own MCAP writes and compression
PIECES = {"frames (decode, JSON, raw record, write)": ("_FRAME",),
          "truth + scene (sim side)": ("_TRUTH",),
          "controller record (daemon side)": ("_CONTROLLER",),
          "logs, sim time": ("_LOG", "_SIM_TIME")}


def _only(batches_file: Path, ops: tuple[str, ...], out_file: Path) -> Path:
    """A copy of the captured batches with only ``ops`` (and the set-up calls) kept."""
    from tfl_mav.flightlog import recorder_process as rp

    keep = {getattr(rp, name) for name in (*ops, "_PATH", "_METADATA", "_CLOSE")}
    batches = [pickle.dumps([it for it in pickle.loads(b) if it[0] in keep])
               for b in pickle.loads(batches_file.read_bytes())]
    out_file.write_bytes(pickle.dumps(batches))
    return out_file


def unpickle_us(batches_file: Path, ticks: int) -> float:
    """CPU µs per tick of unpickling the hand-off batches alone."""
    batches = pickle.loads(batches_file.read_bytes())
    t0 = time.process_time()
    for b in batches:
        pickle.loads(b)
    return (time.process_time() - t0) / max(1, ticks) * 1e6


def _calls(batches_file: Path) -> list[tuple[Any, ...]]:
    """The captured hand-off items, in order (older trees' item layout: see handle_batch)."""
    return [it for b in pickle.loads(batches_file.read_bytes()) for it in pickle.loads(b)]


def handoff_us(batches_file: Path, out: Path, kwargs: dict[str, Any], ticks: int,
               grouped: bool = False) -> dict[str, float]:
    """The flight process's side of the hand-off: the captured calls made on a
    ``RecorderProcess`` with a live child (real time: never waits; room for the whole
    replay, none dropped). ``flight_us``: CPU µs per tick of the calling thread;
    ``process_us``: the whole process's (with the sender thread's pickling and pipe
    writes), until the child has it all; ``grouped``: frames of one direction and time
    stamp (one datagram) as one ``on_frames`` call."""
    from tfl_mav.flightlog import recorder_process as rp

    items = [it for it in _calls(batches_file) if it[0] in (rp._FRAME, rp._TRUTH,
                                                             rp._CONTROLLER)]
    calls: list[tuple[Any, ...]] = []
    for it in items:
        if it[0] != rp._FRAME:
            calls.append(it)
        elif grouped and calls and calls[-1][0] == "grouped" and calls[-1][1] == it[1] \
                and calls[-1][2] == it[2]:
            calls[-1][3].append(it[3])
        else:
            calls.append(("grouped", it[1], it[2], [it[3]]) if grouped else it)
    msg = object()
    rec = rp.RecorderProcess(out, realtime=True, batch_max=1 << 14, **kwargs)
    p0, t0 = time.process_time(), time.thread_time()
    on_frame, on_frames, truth, controller = (rec.on_frame, getattr(rec, "on_frames", None),
                                              rec.truth, rec.controller)
    for c in calls:
        op = c[0]
        if op == rp._FRAME:
            on_frame(c[2], c[3], msg if c[4] else None, c[1])
        elif op == rp._TRUTH:
            truth(*c[2])
        elif op == rp._CONTROLLER:
            controller(c[2], c[3])
        else:
            on_frames(c[2], c[3], None, c[1])
    flight = time.thread_time() - t0
    rec.close()
    proc = time.process_time() - p0
    assert rec.stats.dropped == 0 and rec.error is None, (rec.stats, rec.error)
    return {"flight_us": flight / ticks * 1e6, "process_us": proc / ticks * 1e6,
            "calls_per_s": len(calls) / max(flight, 1e-9)}


def measure(src: Path, repeats: int, profile: bool, compression: str | None,
            tmp: Path) -> dict[str, Any]:
    """Both sides' CPU µs per tick (min of ``repeats``) and, if ``profile``, by piece."""
    out: dict[str, Any] = {}
    for side in ("run", "ctl"):
        kw = _side_kwargs(side)
        if compression:
            kw["compression"] = compression
        runs = [replay(src / f"{side}.mcap.batches", tmp / f"{side}-r.mcap", kw)
                for _ in range(repeats)]
        res: dict[str, Any] = {"ticks": runs[0]["ticks"],
                               "cpu_us_per_tick": min(r["cpu_us_per_tick"] for r in runs),
                               "mib_per_min": runs[0]["bytes"] / 2**20 * 60000
                               / max(1, runs[0]["ticks"])}
        hand = [handoff_us(src / f"{side}.mcap.batches", tmp / f"{side}-h.mcap", kw,
                           res["ticks"]) for _ in range(repeats)]
        res["handoff"] = {k: min(h[k] for h in hand) if k != "calls_per_s"
                          else max(h[k] for h in hand) for k in hand[0]}
        from tfl_mav.flightlog import recorder_process as rp
        if hasattr(rp.RecorderProcess, "on_frames"):    # one on_frames call per datagram
            res["handoff_grouped"] = min(
                handoff_us(src / f"{side}.mcap.batches", tmp / f"{side}-h.mcap", kw,
                           res["ticks"], grouped=True)["flight_us"] for _ in range(repeats))
        if profile:
            src_file = src / f"{side}.mcap.batches"
            res["pieces_us"] = {"hand-off: unpickle": unpickle_us(src_file, res["ticks"])}
            for name, ops in PIECES.items():
                only = _only(src_file, ops, tmp / f"{side}-only.batches")
                res["pieces_us"][name] = min(
                    replay(only, tmp / f"{side}-o.mcap", kw, ticks=res["ticks"])
                    ["cpu_us_per_tick"] for _ in range(repeats))
        out[side] = res
    return out


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--wrap":
        _wrap(sys.argv[2], sys.argv[3], sys.argv[4:])
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=4000)
    ap.add_argument("--scenario", default="paper", help="the captured flight's scenario "
                    "(nominal: no attack, the tick record's estimate is NaN every tick)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--capture", metavar="DIR", help="capture into DIR (kept) and replay")
    ap.add_argument("--replay", metavar="DIR", help="replay an earlier capture, no flight")
    ap.add_argument("--profile", action="store_true",
                    help="also by piece: replays keeping one kind of call each")
    ap.add_argument("--compression", choices=["zstd", "lz4", "none"], default=None)
    ap.add_argument("--tree", metavar="DIR", help=argparse.SUPPRESS)  # a --before child
    ap.add_argument("--before", metavar="DIR", help="also replay with this checkout's "
                    "tfl_mav (e.g. main), alternating, and print both")
    ap.add_argument("--rounds", type=int, default=3, help="alternations with --before")
    ap.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    args = ap.parse_args()
    tmp = tempfile.TemporaryDirectory()
    src = Path(args.replay or args.capture or tmp.name)
    if not args.replay:
        src.mkdir(parents=True, exist_ok=True)
        capture(args.ticks, src, args.scenario)
    if args.tree:                       # a child run for --before: print JSON only
        import tfl_mav

        # its parent put the tree first on PYTHONPATH; an editable install of this
        # checkout would otherwise answer silently, and both columns would be one tree
        here = Path(tfl_mav.__file__).resolve()
        if not here.is_relative_to(Path(args.tree).resolve()):
            raise SystemExit(f"--tree {args.tree}: tfl_mav imported from {here}")
        print(json.dumps(measure(src, args.repeats, args.profile, args.compression,
                                 Path(tmp.name))))
        tmp.cleanup()
        return 0
    rounds = args.rounds if args.before else 1
    now: list[dict[str, Any]] = []
    before: list[dict[str, Any]] = []
    for _ in range(rounds):
        if args.before:
            cmd = [sys.executable, __file__, "--tree", args.before, "--replay", str(src),
                   "--repeats", str(args.repeats)]
            cmd += ["--profile"] if args.profile else []
            cmd += ["--compression", args.compression] if args.compression else []
            # the other checkout's packages ahead of this one's (installed) ones
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(
                filter(None, (args.before, os.environ.get("PYTHONPATH"))))}
            before.append(json.loads(subprocess.run(cmd, check=True, capture_output=True,
                                                    text=True, env=env)
                                     .stdout.splitlines()[-1]))
        now.append(measure(src, args.repeats, args.profile, args.compression, Path(tmp.name)))
    print(f"load {os.getloadavg()[0]:.2f}; batches from {src}; CPU µs per tick, min of "
          f"{args.repeats} runs{f', {rounds} rounds alternating' if args.before else ''}")
    for side, label in (("run", "sim-side child"), ("ctl", "daemon-side child")):
        ticks = now[0][side]["ticks"]
        print(f"\n{label} ({ticks} ticks){'':26s}" + ("   before      now  ratio"
                                                      if args.before else "      now"))
        rows = [(f"round {i + 1}", (before[i][side] if before else None), now[i][side])
                for i in range(rounds)]
        for name, b, n in rows:
            line = f"  {name:44s}"
            if b is not None:
                line += f"{b['cpu_us_per_tick']:9.1f}{n['cpu_us_per_tick']:9.1f}"
                line += f"{n['cpu_us_per_tick'] / b['cpu_us_per_tick']:7.2f}"
            else:
                line += f"{n['cpu_us_per_tick']:9.1f}"
            print(line)
        print(f"  {'file MiB per flight-minute':44s}"
              + (f"{before[0][side]['mib_per_min']:9.1f}" if before else "")
              + f"{now[0][side]['mib_per_min']:9.1f}")
        print("  flight process's hand-off (RecorderProcess calls, live child; least of "
              "the rounds)")
        for k, label in (("flight_us", "calling thread, CPU µs per tick"),
                         ("process_us", "whole process (+ pickling, pipe), µs/tick"),
                         ("calls_per_s", "calls per CPU second (k)")):
            scale = 1e-3 if k == "calls_per_s" else 1.0
            pick = max if k == "calls_per_s" else min
            b = pick(r[side]["handoff"][k] for r in before) * scale if before else None
            v = pick(r[side]["handoff"][k] for r in now) * scale
            print(f"    {label:42s}" + (f"{b:9.1f}" if b is not None else "")
                  + f"{v:9.1f}" + (f"{v / b:7.2f}" if b else ""))
        if "handoff_grouped" in now[0][side]:
            v = min(r[side]["handoff_grouped"] for r in now)
            print(f"    {'calling thread, frames by on_frames':42s}"
                  + (" " * 9 if before else "") + f"{v:9.1f}")
        if args.profile:              # each piece: the least of its rounds
            print("  by piece (replays keeping one kind of call; least of the rounds)")
            for k in now[0][side]["pieces_us"]:
                b = min(r[side]["pieces_us"][k] for r in before) if before else None
                v = min(r[side]["pieces_us"][k] for r in now)
                print(f"    {k:42s}" + (f"{b:9.1f}" if b is not None else "")
                      + f"{v:9.1f}" + (f"{v / b:7.2f}" if b else ""))
    if args.json:
        Path(args.json).write_text(json.dumps({"now": now, "before": before,
                                               "load_1min": os.getloadavg()[0]}, indent=2))
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
