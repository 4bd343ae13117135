"""The seam's front end (:mod:`tfl_mav.accel`): a natural pure function — helpers called,
index loops, tuples and NamedTuples — compiled through it returns the Python function's own
bits (or None where Python raises); what it cannot lower is refused by name."""

from __future__ import annotations

import json
import math
import struct
import sys
from typing import NamedTuple

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tfl_mav.accel import native
from tfl_mav.accel.native import NativeError

pytestmark = pytest.mark.skipif(native.compiler() is None and not native.compiler_expected(),
                                reason="no C compiler, and none expected on this platform")

N_ROTORS = 4
GAIN = 0.75
LIMITS = (-2.0, 2.0)


class Params(NamedTuple):
    k: float
    taus: tuple[float, float, float]
    lim: float = 10.0


def _clamp(x, lo, hi):
    return min(max(x, lo), hi)


def _rotor(p, w, c):
    """One rotor: a helper calling a helper, a tuple result."""
    e = c - w
    for j in range(3):                       # unrolled: the index is read
        w = w + (c - w) * p.taus[j]
    return (_clamp(w * GAIN, *LIMITS), math.sqrt(e * e + p.k))


def natural(p, ws, cs, d):
    """Four rotors through a helper, tuples built, indexed and unpacked, a kept loop."""
    out = ()
    top = 0.0
    for i in range(N_ROTORS):
        w, n = _rotor(p, ws[i], cs[i])
        out += (w,)
        x = 0.0 if d == i + 1 else n
        if x > top:
            top = x
    first, *_ = out[:1]
    s = 0.0
    for _ in range(3):                       # kept: the index is not read
        s = s * 0.5 + first
        if s > 100.0:
            break
    best = max(out)
    z = tuple(abs(out[i]) / p.lim for i in range(N_ROTORS))
    a, b = ws[0], ws[1]
    a, b = b, a                              # read before written
    return (top, out, z, best, s, (a, b), len(out) * 1.0)


_EXAMPLE = (Params(0.5, (0.1, 0.2, 0.3)), (1.0, 2.0, 3.0, 4.0), (0.5, 0.5, 0.5, 0.5), 0.0)
_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)
_SMALL = st.floats(-1e3, 1e3)


def _bits(v):
    if isinstance(v, tuple):
        return tuple(_bits(x) for x in v)
    v = float(v)
    return "nan" if v != v else struct.pack("<d", v)


@pytest.fixture(scope="module")
def compiled():
    return native.build_function(natural, _EXAMPLE)


def _python(fn, *args):
    try:
        return fn(*args)
    except (ValueError, ZeroDivisionError, OverflowError):
        return None


@settings(max_examples=400, deadline=None)
@given(k=_FLOAT, taus=st.tuples(_FLOAT, _FLOAT, _FLOAT), lim=_FLOAT,
       ws=st.tuples(_FLOAT, _SMALL, _SMALL, _FLOAT), cs=st.tuples(_SMALL, _FLOAT, _SMALL, _SMALL),
       d=st.sampled_from([0.0, 1.0, 2.0, 3.0, 4.0]))
def test_the_compiled_natural_function_is_the_python_one_bit_for_bit(compiled, k, taus, lim,
                                                                      ws, cs, d):
    p = Params(k, taus, lim)
    want, got = _python(natural, p, ws, cs, d), compiled(p, ws, cs, d)
    if want is None:                    # Python raises (sqrt of a negative, 0 lim): declined
        assert got is None
    else:
        assert got is not None and _bits(got) == _bits(want)


def test_it_runs_and_declines_where_python_raises(compiled):
    p = Params(0.5, (0.1, 0.2, 0.3))
    assert _bits(compiled(p, *_EXAMPLE[1:])) == _bits(natural(p, *_EXAMPLE[1:]))
    assert compiled(Params(-100.0, (0.1, 0.2, 0.3)), *_EXAMPLE[1:]) is None   # sqrt(< 0)
    assert compiled(p._replace(lim=0.0), *_EXAMPLE[1:]) is None               # / 0
    assert compiled(p, (1.0, 2.0), _EXAMPLE[2], 0.0) is None      # not the example's shape


def test_the_lowered_source_has_no_calls_tuples_or_index_loops():
    src = native.lower(natural, _EXAMPLE)
    assert "_rotor" not in src and "_clamp" not in src and "taus" not in src
    assert src.count("for _ in range(3)") == 1 and "[" not in src


def _root(x):
    return math.sqrt(x)


def call_in_conditional(x):
    """The call only where x ≥ 0 (Python never takes the root of a negative here)."""
    return (_root(x) if x >= 0.0 else -1.0, (x, _root(-x)) if x < 0.0 else (0.0, 0.0))


def call_in_chain(x):
    return (1.0 if 0.0 < x < _root(x) else 0.0,)


def test_a_call_in_a_conditional_expression_runs_only_on_its_branch():
    c = native.build_function(call_in_conditional, (1.0,))
    for x in (4.0, 0.0, -0.0, -9.0, math.inf, -math.inf, math.nan):
        assert _bits(c(x)) == _bits(call_in_conditional(x)), x


def variable_index(t, k):
    return (t[k],)          # k a float: Python raises TypeError on every call


def breaking_index_loop(t):
    s = 0.0
    for i in range(2):
        s += t[i]
        if s > 1.0:
            break
    return (s,)


def _recursive(x):
    return _recursive(x - 1.0)


def recursion(x):
    return (_recursive(x),)


def _in_loop(x):
    for _ in range(3):
        if x > 1.0:
            return (x,)
        x = x * 2.0
    return (x,)


def _early(x):
    if x > 0.0:
        return (x, 1.0)
    return -x


def returns_of_two_shapes(x):
    return _early(x)


def shape_in_branch(x):
    t = (x,)
    if x > 0.0:
        t = (x, x)
    return t


def unknown_call(t):
    return tuple(sorted(t))


def tuple_in_compare(t):
    return (1.0 if t > (0.0, 0.0) else 0.0,)


@pytest.mark.parametrize("fn, example, match", [
    (call_in_chain, (1.0,), "some paths only"),
    (breaking_index_loop, ((1.0, 2.0),), "cannot break"),
    (recursion, (1.0,), "recursive"),
    (_in_loop, (1.0,), "a return inside a loop"),
    (returns_of_two_shapes, (1.0,), "returns differ in shape"),
    (shape_in_branch, (1.0,), "changes shape in a branch"),
    (unknown_call, ((1.0, 2.0),), "neither a pure Python function"),
    (tuple_in_compare, ((1.0, 2.0),), "not a number here"),
    (natural, _EXAMPLE[:3], "3 example arguments"),
    (natural, (None, *_EXAMPLE[1:]), "must be a number or a non-empty tuple"),
])
def test_what_the_front_end_cannot_lower_is_refused_by_name(fn, example, match):
    with pytest.raises(NativeError, match=match):
        native.lower(fn, example)


def test_a_variable_index_that_is_not_an_int_is_refused_by_name():
    with pytest.raises(NativeError, match="a variable index must be an int"):
        native.c_source(native.lower(variable_index, ((1.0, 2.0), 0.0)))


def test_obtain_function_warns_and_declines_what_it_cannot_lower(monkeypatch, caplog):
    monkeypatch.setenv("TFL_MAV_NATIVE", "sync")
    with caplog.at_level("WARNING", logger="tfl_mav.accel.native"):
        assert native.obtain_function(recursion, (1.0,), lambda core: None) is None
    assert "recursive" in caplog.text
    assert native.obtain_function(natural, _EXAMPLE, lambda core: None) is not None


def test_a_kept_lowering_is_used_until_a_constant_it_folded_in_changes(tmp_path, monkeypatch):
    """native.lowered keeps a lowering on disk; it is taken while the functions' files and
    the module constants it read are as they were, and lowered afresh once one changes."""
    monkeypatch.setenv("TFL_MAV_KERNEL_CACHE", str(tmp_path))
    native.forget()             # as a new process: nothing lowered in memory
    first = native.lowered(natural, _EXAMPLE)
    (kept,) = tmp_path.glob("_tflf_*.json")
    entry = json.loads(kept.read_text())
    assert [__name__, "GAIN", "0.75"] in entry["constants"]
    kept.write_text(json.dumps({**entry, "source": "marker"}))
    native.forget()
    assert native.lowered(natural, _EXAMPLE) == "marker"        # the kept one
    monkeypatch.setattr(sys.modules[__name__], "GAIN", 0.5)
    native.forget()
    again = native.lowered(natural, _EXAMPLE)
    assert again != first and "0.5" in again
