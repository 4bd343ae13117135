"""``tfl-mav`` subprocesses for tests and benchmarks: start, watch their output, stop.

Two ways to run one:

* :class:`Proc` reads stdout and stderr on threads and stamps every line with
  ``time.monotonic()`` on arrival, so a test can time events from outside
  (:meth:`Proc.wait_for`), e.g. "motors cut" 0.25 s after a SIGKILL;
* :func:`popen_sim` starts ``tfl-mav sim`` as a plain :class:`subprocess.Popen` with
  pipes (for ``communicate()``), once it is listening.

Both run ``python -m tfl_mav.tools.cli.main`` with this interpreter: the installed package, whatever
the working directory.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from tfl_mav.link.transport import Address

__all__ = ["CLI", "LISTEN_RE", "Proc", "popen_sim", "raise_priority", "start_sim",
           "start_sim_on"]

CLI = [sys.executable, "-m", "tfl_mav.tools.cli"]
LISTEN_RE = re.compile(r"listening on ([\d.]+):(\d+)")
"""The first line ``tfl-mav sim`` prints: its control address."""
REALTIME_NICE = -10
START_TIMEOUT_S = 30.0       # a cold interpreter importing numpy/scipy on a loaded machine


def raise_priority(tid: int = 0) -> bool:
    """Run the calling process (or thread ``tid``) at nice ``REALTIME_NICE`` if allowed.

    Why: a real-time loop at 1 kHz tolerates ~4 ms of delay (offline, 6 ticks of command
    delay flip the paper scenario), and on 2 shared cores other jobs add scheduling delays
    of that size. A flight stack runs its loop at real-time priority for the same reason.
    Without the privilege the run goes on at normal priority.
    """
    try:
        os.setpriority(os.PRIO_PROCESS, tid, REALTIME_NICE)
        return True
    except OSError:
        return False


class Proc:
    """A ``tfl-mav`` subprocess whose output lines are read on threads and stamped with
    ``time.monotonic()`` when they arrive, so events can be timed from outside.

    ``realtime``: raise its priority (:func:`raise_priority`); ``new_session``: its own
    process group (so ``os.killpg`` reaches its children too).
    """

    def __init__(self, args: Sequence[str], *, realtime: bool = False,
                 new_session: bool = False) -> None:
        self.popen = subprocess.Popen([*CLI, *args], stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True,
                                      preexec_fn=raise_priority if realtime else None,
                                      start_new_session=new_session)
        self.lines: list[tuple[float, str]] = []
        self.out_lines: list[str] = []
        self.err_lines: list[str] = []
        self._cv = threading.Condition()
        self._readers = [
            threading.Thread(target=self._read, args=(self.popen.stdout, self.out_lines),
                             daemon=True),
            threading.Thread(target=self._read, args=(self.popen.stderr, self.err_lines),
                             daemon=True)]
        for t in self._readers:
            t.start()

    @property
    def pid(self) -> int:
        return self.popen.pid

    @property
    def returncode(self) -> int | None:
        return self.popen.returncode

    def _read(self, stream: Any, sink: list[str]) -> None:
        for line in stream:
            with self._cv:
                text = line.rstrip("\n")
                self.lines.append((time.monotonic(), text))
                sink.append(text)
                self._cv.notify_all()

    def wait_for(self, pattern: str, timeout_s: float, after: float = 0.0
                 ) -> tuple[float, re.Match[str]]:
        """(arrival time, match) of the first line at/after ``after`` matching ``pattern``;
        TimeoutError if none within ``timeout_s``."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while True:
                for t, line in self.lines:
                    if t >= after and (m := rx.search(line)):
                        return t, m
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no line matching {pattern!r} within {timeout_s} s:\n"
                                       + "\n".join(x for _, x in self.lines[-20:]))
                self._cv.wait(left)

    def text(self) -> str:
        """Everything it printed so far, stdout and stderr interleaved by arrival."""
        with self._cv:
            return "\n".join(line for _, line in self.lines)

    def stdout(self) -> str:
        """Its stdout (complete once :meth:`wait` returned)."""
        with self._cv:
            return "\n".join(self.out_lines)

    def stderr(self) -> str:
        """Its stderr (complete once :meth:`wait` returned)."""
        with self._cv:
            return "\n".join(self.err_lines)

    def signal(self, signum: int) -> None:
        self.popen.send_signal(signum)

    def kill(self) -> float:
        """SIGKILL now; returns the time it was sent."""
        t = time.monotonic()
        self.popen.send_signal(signal.SIGKILL)
        self.popen.wait(timeout=10)
        return t

    def wait(self, timeout_s: float) -> int:
        """Its exit code, once it exited and its output was read to the end."""
        code = self.popen.wait(timeout=timeout_s)
        for t in self._readers:
            t.join(timeout=5.0)
        return code

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM (a clean stop: files finished, report written), SIGKILL if it has not
        exited after ``timeout_s``; its exit code."""
        if self.popen.poll() is None:
            self.popen.terminate()
            try:
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.close()
        return self.popen.returncode

    def close(self) -> None:
        """SIGKILL if still running."""
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait(timeout=10)


def start_sim(args: Sequence[str], scenario: str = "paper", *,
              new_session: bool = False) -> tuple[Proc, int]:
    """``tfl-mav sim SCENARIO --listen 127.0.0.1:0 ARGS`` once it listens; (proc, port)."""
    sim = Proc(["sim", scenario, "--listen", "127.0.0.1:0", *args],
               realtime="--realtime" in args, new_session=new_session)
    try:
        _, m = sim.wait_for(LISTEN_RE.pattern, START_TIMEOUT_S)
    except TimeoutError:
        sim.close()
        raise
    return sim, int(m.group(2))


def start_sim_on(port: int, args: Sequence[str], scenario: str = "paper",
                 timeout_s: float = 10.0) -> Proc:
    """A vehicle on a fixed port (a restarted one), retrying while the port is busy."""
    deadline = time.monotonic() + timeout_s
    while True:
        sim = Proc(["sim", scenario, "--listen", f"127.0.0.1:{port}", *args],
                   realtime="--realtime" in args)
        try:
            sim.wait_for(LISTEN_RE.pattern, START_TIMEOUT_S)
            return sim
        except TimeoutError:
            sim.close()
            if time.monotonic() > deadline:
                raise


def popen_sim(args: Sequence[str] = (), scenario: str | None = None,
              **popen_kw: Any) -> tuple[subprocess.Popen[str], Address]:
    """``tfl-mav sim [SCENARIO] --listen 127.0.0.1:0 ARGS`` with stdout/stderr piped
    (text), returned once its first line says where it listens: (popen, address).
    RuntimeError (with its output) if it does not start."""
    cmd = [*CLI, "sim", *([scenario] if scenario else []), "--listen", "127.0.0.1:0", *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            **popen_kw)
    assert proc.stdout is not None and proc.stderr is not None
    line = proc.stdout.readline()
    match = LISTEN_RE.search(line)
    if not match:
        if proc.poll() is None:
            proc.kill()
        raise RuntimeError(f"sim did not start: {line}{proc.stderr.read()}")
    return proc, (match.group(1), int(match.group(2)))
