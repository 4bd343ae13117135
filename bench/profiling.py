"""Per-process CPU of a multi-process flight, and where it goes (bench/bench_lockstep.py).

Two measurements, because profiling distorts what it measures:

* :class:`ProcessCPU` reads ``utime + stime`` of a process tree from ``/proc`` (the sim, the
  daemon and their MCAP recorder children) at moments the caller chooses, e.g. on each of
  ``tfl-mav fly --progress``'s lines: the CPU each process spent over a window of known
  ticks, unprofiled, start-up excluded.
* A second, profiled run: ``python bench/profiling.py OUT.prof MODULE ARGS...`` runs
  ``python -m MODULE ARGS...`` under :mod:`cProfile` with a **CPU** timer (on 2 shared cores
  four processes wait for the CPU a lot; a wall-clock profile would charge that waiting to
  whatever call was preempted, typically ``sendto``). The recorder children profile
  themselves when ``TFL_MAV_PROFILE=DIR`` is set (:mod:`tfl_mav.flightlog.recorder_process`).
  :func:`categorize` splits a profile's self time into named categories; the bench scales
  those shares to the unprofiled CPU per tick.
"""

from __future__ import annotations

import cProfile
import os
import pstats
import runpy
import sys
import time
from collections.abc import Sequence
from pathlib import Path

__all__ = ["CATEGORIES", "STARTUP", "ProcessCPU", "categorize"]

_CLK_TCK = os.sysconf("SC_CLK_TCK")

# (category, substrings of "file:function"); first match wins, per process role.
_LINK = [("decode (link)", ("link/codec.py:decode", "<codec", "transport.py:_ingest",
                            "transport.py:_decode_frame", "receive.py:_ingest",
                            "receive.py:_decode_other", "pymavlink", "ardupilotmega.py")),
         ("pack (link)", ("link/codec.py:pack", "transport.py:send", "signing.py")),
         ("syscalls (sendto, recvfrom, select/poll)", ("sendto", "recvfrom", "select",
                                                       "'poll'", "transport.py:recv",
                                                       "receive.py:recv"))]
_HANDOFF = [("recorder hand-off (queue, pickle, pipe)",
             ("recorder_process.py", "pickle", "connection.py", "threading.py",
              "_thread", "'acquire'", "'wait'"))]
CATEGORIES: dict[str, list[tuple[str, tuple[str, ...]]]] = {
    "sim": [("physics + motors + attacker + power", ("sitl/physics.py",
                                                     "sitl/motors.py",
                                                     "sitl/attacker.py",
                                                     "sitl/power.py",
                                                     "sitl/simulator.py")),
            ("state messages built (frames, pymavlink objects)",
             ("state_report.py", "tfl_mav/model/frames.py", "ardupilotmega.py:__init__")),
            ("gcs telemetry", ("sitl/gcs.py",)),
            *_LINK, *_HANDOFF,
            ("vehicle loop (clock, commands)", ("sitl/",))],
    "daemon": [("frames (paper_from_odometry)", ("tfl_mav/model/frames.py",)),
               ("flight computer (law, detector)", ("flight_computer.py", "tfl_mav/control/",
                                                    "numpy", "scipy", "linalg", "math")),
               *_LINK, *_HANDOFF,
               ("daemon tick (classify, telemetry)", ("daemon.py", "tools/cli/fly.py"))],
    "recorder": [("pipe read + unpickle", ("'read'", "posix.read", "connection.py",
                                           "pickle", "_pickle", "'loads'")),
                 ("decode (payload)", ("payload.py", "link/codec.py", "<codec")),
                 ("JSON", ("msgspec", "json/", "_json", "'encode'",
                           "isfinite")),
                 ("compression (zstd/lz4)", ("compress", "zstandard", "lz4")),
                 ("MCAP write", ("mcap/", "mcapout.py", "foxglove", "BytesIO",
                                 "_struct", "'pack'", "'write'", "crc32")),
                 ("protobuf (records, scene, tf, log)", ("protos.py", "protobuf", "messages")),
                 ("frame/record handling", ("recorder.py", "framerec.py", "b64encode",
                                            "base64"))],
}


_STARTUP = ("importlib", "<frozen", "marshal", "builtins.compile", "builtins.exec",
            "_imp.", "__build_class__", "re/_", "inspect.py", "enum.py", "dataclasses.py",
            "typing.py", "abc.py", "tomllib", "argparse.py")
STARTUP = "start-up (imports, compile; not per tick)"


def categorize(prof_path: str | Path, role: str) -> dict[str, float]:
    """Self CPU seconds of a profile, by :data:`CATEGORIES` ``[role]``. A function no rule
    names (a builtin such as ``struct.pack`` or ``len``) is charged to its callers, in
    proportion, by their names; the rest is ``"other"``. Start-up work (imports, code
    generation) is :data:`STARTUP`, to be left out of per-tick figures."""
    stats = pstats.Stats(str(prof_path)).stats   # type: ignore[attr-defined]
    rules = [(STARTUP, _STARTUP), *CATEGORIES[role]]
    out = dict.fromkeys([name for name, _ in rules] + ["other"], 0.0)

    def match(func: tuple[str, int, str]) -> str | None:
        key = f"{func[0]}:{func[2]}".replace("\\", "/")
        for name, needles in rules:
            if any(n in key for n in needles):
                return name
        return None

    for func, (_cc, _nc, tottime, _ct, callers) in stats.items():
        name = match(func)
        if name is not None:
            out[name] += tottime
            continue
        edges = [(match(caller), edge[2]) for caller, edge in callers.items()]
        weight = sum(w for _, w in edges)
        if weight <= 0.0:
            out["other"] += tottime
            continue
        for caller_name, w in edges:
            out[caller_name or "other"] += tottime * w / weight
    return out


class ProcessCPU:
    """CPU seconds (user + system) of processes and all their descendants, from /proc."""

    def __init__(self, roots: dict[int, str]) -> None:
        self.roots = dict(roots)        # pid → label

    def snapshot(self) -> dict[str, float]:
        """label → CPU seconds now; a descendant is labelled ``"<root> child <pid>"``
        (the recorder child of ``tfl-mav sim --mcap`` / ``fly --mcap``)."""
        procs: dict[int, tuple[int, float]] = {}
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            try:
                text = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            fields = text[text.rindex(")") + 2:].split()
            procs[int(entry)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / _CLK_TCK)
        out: dict[str, float] = {}
        for pid, label in self.roots.items():
            if pid in procs:
                out[label] = procs[pid][1]
            for child, (ppid, cpu) in procs.items():
                if ppid == pid:
                    out[f"{label} child {child}"] = cpu
        return out

    def child_policies(self) -> dict[str, str]:
        """``"<root> recorder child"`` → its scheduling policy now (``SCHED_IDLE`` in
        lockstep where it can be promoted back: ``tfl_mav.flightlog.child_priority``).
        Only the recorder (``multiprocessing.spawn``) children, not the resource tracker."""
        names = {getattr(os, n): n for n in ("SCHED_OTHER", "SCHED_IDLE", "SCHED_BATCH")
                 if hasattr(os, n)}
        out: dict[str, str] = {}
        for label in self.snapshot():
            if " child " not in label:
                continue
            pid = int(label.rsplit(" ", 1)[1])
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
                if b"multiprocessing.spawn" not in cmd:
                    continue
                policy = os.sched_getscheduler(pid)
            except OSError:
                continue
            out[f"{label.split(' child ')[0]} recorder child"] = names.get(policy, str(policy))
        return out


def _run(out: str, module: str, args: Sequence[str]) -> int:
    sys.argv = [module, *args]
    prof = cProfile.Profile(time.process_time)
    code = 0
    try:
        prof.runcall(runpy.run_module, module, run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 0
    finally:
        prof.dump_stats(out)
    return code


if __name__ == "__main__":
    sys.exit(_run(sys.argv[1], sys.argv[2], sys.argv[3:]))
