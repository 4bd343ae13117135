"""Generated float code compiled to machine code with the system C compiler.

The law's step (:func:`tfl_mav.control.tfl.step.tfl_step`) is Python: ~1 000 float
operations a tick, each a bytecode dispatch and a float object. Lowered by the front end
(:mod:`frontend`) into one straight-line function, it is *translated from that very Python
source* into C (:mod:`ctranslate`), built here with ``cc`` into a CPython extension and
cached, as CasADi and acados build their generated code. The translation keeps every
operation, operand and order: IEEE-754 ``+ − × ÷`` and ``sqrt`` are correctly rounded in
both languages, the other math functions are the same libm's (CPython's ``math`` calls them
too), and the build forbids what would change a bit (``-ffp-contract=off``: no fused
multiply-add; ``-fno-builtin``: libm calls stay calls, no ``pow(x, 2) → x·x``; no
``-ffast-math``). So the compiled core returns the Python core's floats bit for bit
(tests/contract/test_native.py checks it on random states and whole flights) — every number,
that is: a NaN's sign and payload, which IEEE 754 leaves unspecified, may differ (a compiler
may swap a commutative operation's operands).

Where the Python core would raise (a division by zero, ``sqrt`` of a negative, an overflow
of ``**``/``exp``, ``sin`` of ±∞, a ``log`` of a non-positive) — and on any argument that is
not a number — the compiled core returns ``None`` instead, as the Python core returns on its
own checks; the caller then runs the Python tick, which decides as before.

Building is optional and never on the control path's clock: ``TFL_MAV_NATIVE`` = ``auto``
(default: a cached build is loaded at once, else one is made in a background thread and the
controller switches to it when it is ready — the results are the same bits, so the switch is
invisible), ``sync`` (build before returning: benchmarks, tests) or ``off``. No compiler, no
headers, a failed build: the Python core keeps flying and one warning says why. Cache:
``TFL_MAV_KERNEL_CACHE``, else ``$XDG_CACHE_HOME/tfl-mav/kernels`` (``~/.cache``), one file
per source hash, written atomically.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.machinery
import importlib.util
import json
import linecache
import logging
import os
import queue
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import threading
import time
import types
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:         # not POSIX: concurrent processes may build the same source twice
    fcntl = None  # type: ignore[assignment]

from tfl_mav.accel import ctranslate, frontend
from tfl_mav.accel.ctranslate import NativeError, translate
from tfl_mav.accel.frontend import lower

__all__ = ["NativeError", "build", "build_function", "c_source", "cache_dir", "compile_async",
           "compiler", "forget", "load_cached", "lower", "lowered", "mode", "obtain",
           "obtain_function", "translate", "waiting", "warn_once"]

log = logging.getLogger(__name__)

Core = Callable[..., "tuple[float, ...] | None"]

#: Flags that keep the C arithmetic bit-identical to CPython's (see the module doc).
CFLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-builtin", "-fno-fast-math",
          "-fno-strict-aliasing", "-fvisibility=hidden")


def mode() -> str:
    """``TFL_MAV_NATIVE``: ``auto`` (default), ``sync`` or ``off``."""
    m = os.environ.get("TFL_MAV_NATIVE", "auto").strip().lower() or "auto"
    if m not in ("auto", "sync", "off"):
        log.warning("TFL_MAV_NATIVE=%r is not auto, sync or off; using off", m)
        return "off"
    return m


def cache_dir() -> Path:
    """Where built kernels are kept (``TFL_MAV_KERNEL_CACHE``, else the user's cache)."""
    env = os.environ.get("TFL_MAV_KERNEL_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "tfl-mav" / "kernels"


# ----- build, cache, load -------------------------------------------------------------------
def compiler_expected() -> bool:
    """True where a C compiler is part of the platform the project is built for (Linux),
    or when ``TFL_MAV_EXPECT_COMPILER=1`` says so: the contract tests then fail without
    one instead of skipping."""
    flag = os.environ.get("TFL_MAV_EXPECT_COMPILER")
    if flag is not None:
        return flag == "1"
    return sys.platform.startswith("linux")


def compiler() -> list[str] | None:
    """The C compiler the seam builds with, as an argv (``$CC``, else the one Python was
    built with, else ``cc``), or None when it is not on ``PATH``: the compiled cores then
    stay off and the Python ones fly."""
    cc = os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc"
    argv = shlex.split(cc)
    if not argv or shutil.which(argv[0]) is None:
        return None
    return argv


@functools.cache
def _translator() -> str:
    """The translator's own source, hashed: a changed translation is a new cache entry."""
    here = Path(__file__).parent
    text = Path(ctranslate.__file__).read_bytes() + b"".join(
        (here / name).read_bytes() for name in ("cruntime.py", "frontend.py", "lowering.py",
                                                  "lowering_values.py"))
    return hashlib.sha256(text).hexdigest()[:16]


def _key(source: str) -> str:
    tag = (f"{_translator()}|{sys.version}|{sysconfig.get_config_var('EXT_SUFFIX')}|"
           f"{CFLAGS}|{os.environ.get('CC', '')}")
    return hashlib.sha256((tag + "\0" + source).encode()).hexdigest()[:20]


def _paths(source: str) -> tuple[str, Path]:
    module = f"_tflk_{_key(source)}"
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    return module, cache_dir() / f"{module}{suffix}"


def _import(module: str, path: Path, fn: str) -> Core:
    loader = importlib.machinery.ExtensionFileLoader(module, str(path))
    spec = importlib.util.spec_from_file_location(module, str(path), loader=loader)
    assert spec is not None
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return getattr(mod, fn)  # type: ignore[no-any-return]


def _fn_name(source: str) -> str:
    return source.split("def ", 1)[1].split("(", 1)[0].strip()


def _c_text(source: str, module: str) -> str:
    """The C translation of the Python ``source``."""
    return translate(source, module)


def load_cached(source: str) -> Core | None:
    """The compiled function for ``source`` if this process has it or the cache holds it
    (no build)."""
    module, path = _paths(source)
    core = _loaded.get(module)
    if core is not None:
        return core
    if not path.exists():
        return None
    try:
        core = _loaded[module] = _import(module, path, _fn_name(source))
        return core
    except (ImportError, OSError) as exc:
        log.warning("native kernel %s does not load (%s); rebuilding", path.name, exc)
        return None


def c_source(source: str) -> str:
    """The C translation of ``source`` as :func:`build` compiles it."""
    return _c_text(source, _paths(source)[0])


def build(source: str, c_text: str | None = None) -> Core:
    """Translate (unless ``c_text`` is given), compile (or take from the cache) and load
    ``source``'s function. The compiler runs at the lowest CPU priority: a flight that
    is already running keeps the processor."""
    cached = load_cached(source)
    if cached is not None:
        return cached
    module, path = _paths(source)
    c_text = c_text if c_text is not None else _c_text(source, module)
    path.parent.mkdir(parents=True, exist_ok=True)
    # One build per source across processes (a campaign's runs start together): the others
    # wait for the lock and find the build in the cache.
    with open(path.with_name(f".{path.name}.lock"), "a+") as lock:
        if fcntl is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)
        cached = load_cached(source)
        if cached is not None:
            return cached
        _compile(c_text, module, path)
    core = _loaded[module] = _import(module, path, _fn_name(source))
    return core


def _compile(c_text: str, module: str, path: Path) -> None:
    """``cc`` ``c_text`` into the extension ``path`` (atomically: a temporary, then rename)."""
    cc = compiler()
    if cc is None:
        raise NativeError("no C compiler (set CC, or install gcc)")
    include = sysconfig.get_paths()["include"]
    if not os.path.exists(os.path.join(include, "Python.h")):
        raise NativeError(f"no Python.h under {include} (install the Python headers)")
    _sweep(path.parent)
    # In the cache directory, so that a build an exiting process left behind (its builder
    # is a daemon thread) is found and removed by the next build.
    with tempfile.TemporaryDirectory(prefix=_BUILD_PREFIX, dir=path.parent) as tmp:
        src = Path(tmp) / f"{module}.c"
        src.write_text(c_text)
        out = Path(tmp) / path.name
        argv = [*cc, *CFLAGS, f"-I{include}", str(src), "-o", str(out), "-lm"]
        t0 = time.perf_counter()
        done = subprocess.run(argv, capture_output=True, text=True, check=False,
                              preexec_fn=_lowest_priority)
        if done.returncode != 0:
            last = done.stderr.strip().splitlines()[-1:] or [""]
            raise NativeError(f"{cc[0]} failed ({done.returncode}): {last[0]}")
        log.debug("built %s in %.2f s", path.name, time.perf_counter() - t0)
        tmp_dest = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        shutil.copyfile(out, tmp_dest)
        os.replace(tmp_dest, path)          # atomic: a concurrent build writes the same bytes


_BUILD_PREFIX = ".build-"
_STALE_BUILD_S = 3600.0         # far longer than any compile of a generated kernel


def _sweep(cache: Path) -> None:
    """Remove build directories older than an hour: left by processes that exited while
    their background build ran (the daemon thread dies with them; the compiler did not)."""
    now = time.time()
    for stale in cache.glob(f"{_BUILD_PREFIX}*"):
        try:
            if now - stale.stat().st_mtime > _STALE_BUILD_S:
                shutil.rmtree(stale, ignore_errors=True)
        except OSError:
            pass


def _lowest_priority() -> None:
    os.nice(19)


# ----- background builds --------------------------------------------------------------------
_jobs: queue.Queue[tuple[str, str]] = queue.Queue()
_worker: threading.Thread | None = None
_lock = threading.Lock()
_warned: set[str] = set()
# This process's builds, by source key: loaded, waiting (their callbacks), failed. A
# campaign flies one source many times: it is translated, built and loaded once.
_loaded: dict[str, Core] = {}
_waiting: dict[str, list[Callable[[Core], None]]] = {}
_failed: set[str] = set()


def _after_fork_in_child() -> None:
    """A forked child (a campaign run) starts with no worker and fresh locks: the parent's
    worker thread does not exist there, and a lock it held at the fork would stay held."""
    global _jobs, _worker, _lock
    _jobs = queue.Queue()
    _worker = None
    _lock = threading.Lock()
    _waiting.clear()


os.register_at_fork(after_in_child=_after_fork_in_child)


def warn_once(msg: str) -> None:
    """One warning per distinct reason the compiled core is not used."""
    if msg not in _warned:
        _warned.add(msg)
        log.warning("the law's compiled core is not available (%s); the Python core flies "
                    "(the same numbers, slower)", msg)


def waiting(source: str) -> int:
    """How many asks (their ``ready`` callbacks) wait for ``source``'s background build in
    this process: 0 when none is under way."""
    with _lock:
        return len(_waiting.get(_paths(source)[0], ()))


def forget() -> None:
    """Forget what this process has loaded, lowered, failed to build and warned about (the
    cache directory keeps its builds and lowerings): the next ask is answered as in a new
    process — from the cache, or a build. For a long-lived interpreter whose laws' module
    constants changed (a lowering is kept in memory on the functions' files alone), and
    for a test of what a fresh process does. Builds under way still call their askers."""
    with _lock:
        _loaded.clear()
        _lowered.clear()
        _failed.clear()
        _warned.clear()


def _work() -> None:
    while True:
        source, c_text = _jobs.get()
        module = _paths(source)[0]
        try:
            core: Core | None = build(source, c_text)
        except (NativeError, OSError, ImportError) as exc:
            warn_once(str(exc))
            core = None
        with _lock:
            callbacks = _waiting.pop(module, [])
            if core is None:
                _failed.add(module)
        for done in callbacks if core is not None else ():
            done(core)


def obtain(source: str, ready: Callable[[Core], None], *, now: bool = True) -> Core | None:
    """The compiled function of ``source`` now — loaded already, cached, or built here when
    ``TFL_MAV_NATIVE=sync`` — else None, and with ``auto`` a background build calls
    ``ready(core)`` when it is done (one build per source however many ask). ``off``, no
    compiler, a failed build: None (one warning). The translation (which holds the GIL)
    happens here, before any flight, once per source. ``now=False``: never build here,
    ``sync`` included — for a step made during a flight, whose tick must not wait for the
    compiler (the Python step flies until ``ready``: the same numbers)."""
    how = mode()
    if how == "off":
        return None
    module = _paths(source)[0]
    with _lock:
        if module in _failed:
            return None
        waiting = _waiting.get(module)
        if waiting is not None:         # a build of it is under way: wait with the others
            waiting.append(ready)
            return None
    try:
        core = load_cached(source)
        if core is None and how == "sync" and now:
            core = build(source)
        if core is not None:
            return core
        c_text = c_source(source)
    except (NativeError, OSError, ImportError) as exc:     # no compiler, a cache not writable
        with _lock:
            _failed.add(module)
        warn_once(str(exc))
        return None
    compile_async(source, c_text, ready)
    return None


def obtain_function(fn: Callable[..., Any], example: Sequence[Any],
                    ready: Callable[[Core], None], *, now: bool = True) -> Core | None:
    """:func:`obtain` for a pure Python function itself: lowered first (:func:`frontend.lower`:
    its calls inlined, its index loops unrolled, its tuples scalar-replaced, for arguments
    shaped like ``example``). A function the front end cannot lower is a warning and None,
    as a failed build is."""
    if mode() == "off":
        return None
    try:
        source = lowered(fn, example)
    except NativeError as exc:
        warn_once(str(exc))
        return None
    return obtain(source, ready, now=now)


def build_function(fn: Callable[..., Any], example: Sequence[Any]) -> Core:
    """:func:`build` of a pure Python function (lowered as :func:`obtain_function` does)."""
    return build(lowered(fn, example))


_lowered: dict[tuple[Any, str, tuple[Any, ...]], str] = {}


def lowered(fn: Callable[..., Any], example: Sequence[Any]) -> str:
    """:func:`frontend.lower`'s source, kept: in this process, and in the cache directory
    with the hashes of the source files it was lowered from (a process that flies once
    would otherwise spend a tenth of a second lowering the detector)."""
    kernels = frontend.bound_functions(example)
    key = (fn, frontend.shape_key(example), kernels)
    source = _lowered.get(key)
    if source is not None:
        return source
    # A function on generated code (a path's kernels, passed in) is another lowering.
    # A function bound at lowering is named (its file's hash validates the entry, as for
    # any function read); generated code is named by its text's hash too.
    linked = [f"{g.__module__}.{g.__qualname__}" for g in kernels] + sorted(
        _file_hash(g.__code__.co_filename) for g in (
            *kernels, *getattr(fn, "__globals__", {}).values())
        if isinstance(g, types.FunctionType) and g.__code__.co_filename.startswith("<"))
    # The function's own file is part of the name: two checkouts share one cache, and an
    # entry validated against the other checkout's files (unchanged there) is that tree's
    # lowering, not this one's.
    name = hashlib.sha256(f"{_translator()}|{fn.__module__}.{fn.__qualname__}|"
                          f"{fn.__code__.co_filename}|{key[1]}|{linked}".encode()
                          ).hexdigest()[:20]
    path = cache_dir() / f"_tflf_{name}.json"
    try:
        entry = json.loads(path.read_text())
        if all(_file_hash(f) == h for f, h in entry["files"].items()) and all(
                _constant(m, n) == text for m, n, text in entry["constants"]):
            source = _lowered[key] = entry["source"]
            return source
    except (OSError, ValueError, KeyError, TypeError, AttributeError, ImportError):
        pass
    source, files, constants = frontend.lower_files(fn, example)
    _lowered[key] = source
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"source": source,
                                   "files": {f: _file_hash(f) for f in sorted(files)},
                                   "constants": sorted([m, n, text] for (m, n), text
                                                       in constants.items())}))
        os.replace(tmp, path)
    except OSError:
        pass                # not kept: lowered again next time
    return source


def _constant(module: str, name: str) -> str:
    """The repr of a module's constant now (what a kept lowering folded in); a dotted name
    is a class's attribute (an IntEnum member)."""
    head, *rest = name.split(".")
    value = vars(importlib.import_module(module)).get(head)
    for part in rest:
        value = getattr(value, part, None)
    return repr(value)


def _file_hash(path: str) -> str:
    """A source file's hash; generated code's (``<…>``) from its text in linecache."""
    if path.startswith("<"):
        return hashlib.sha256("".join(linecache.getlines(path)).encode()).hexdigest()
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def compile_async(source: str, c_text: str, done: Callable[[Core], None]) -> None:
    """Build ``source`` (translated: ``c_text``) on a background thread — the compiler is a
    subprocess, outside the GIL — and call ``done(core)`` there when it is ready; a failure
    is logged once and ``done`` is not called."""
    global _worker
    module = _paths(source)[0]
    with _lock:
        if _worker is None or not _worker.is_alive():
            # A daemon thread: an interpreter that exits does not wait for a build.
            _worker = threading.Thread(target=_work, name="tfl-mav-native", daemon=True)
            _worker.start()
        waiting = _waiting.setdefault(module, [])
        waiting.append(done)
        if len(waiting) > 1:
            return
    _jobs.put((source, c_text))
