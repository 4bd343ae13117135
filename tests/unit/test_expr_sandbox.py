"""Scenario expressions cannot execute code or exhaust the machine.

Attack signals (``attack.signal``) and expression paths (``path.s[i]``, ``path.sigma[i]``)
are compiled by :mod:`tfl_mav.expr`. Every hostile text must be refused at load time with
one line naming the field, quickly, and without running anything.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from tfl_mav.expr import MAX_EXPR_LENGTH, ExprError, compile_expr
from tfl_mav.from_scenario import scenario_path
from tfl_mav.scenario import ScenarioError, scenario_from_dict

# Each line: code execution, escape or DoS attempt; all must be refused.
HOSTILE = [
    "__import__('os').system('touch {canary}')",
    "__import__('pathlib').Path('{canary}').touch()",
    "open('{canary}', 'w')",
    "exec('import os')", "eval('1')", "compile('1', 'f', 'eval')", "globals()", "vars()",
    "getattr(t, 'real')", "().__class__", "().__class__.__bases__[0].__subclasses__()",
    "t.__class__", "sin.__self__", "abs.__module__",
    "lambda: 1", "(lambda: 1)()", "[t for t in (1,)]", "{t for t in (1,)}",
    "(t for t in (1,))", "{t: 1 for t in (1,)}",
    "[1][0]", "t[0]", "'abc'[0]",
    "f'{t}'", "'a' * 10**9", "b'x'", "'x'",
    "(y := 1)", "max(*t)", "max(**t)", "sin(x=t)",
    "t if t else 1", "t < 1", "t and 1", "not t", "~t", "t % 2", "t // 2", "t << 2",
    "t @ t", "[1, 2]", "(1, 2)", "{1: 2}", "{1}", "None", "True", "...", "1j",
    "9**9**9", "10**10**10", "2.0**1e10", "1/0", "exp(1e4)", "1e999", "1" + "0" * 400,
    "1e308 * 10", "-" * 1990 + "t", "(" * 300 + "t" + ")" * 300, "t" + " + t" * 600,
    "t" + "**t" * 700, "x" * (MAX_EXPR_LENGTH + 1), "sin(" * 500 + "t" + ")" * 500,
    "unknown", "open", "__builtins__", "sin", "os", "import os", "t = 1", "t; t", "",
    "   ", "t\x00", "sin()", "sin(t, t)", "max(t)", "clip(t, 1)",
]


def _texts(canary: Path) -> list[str]:
    return [h.replace("{canary}", str(canary)) for h in HOSTILE]


@pytest.mark.parametrize("index", range(len(HOSTILE)))
def test_hostile_attack_signal_is_refused_naming_the_field(tmp_path: Path,
                                                           index: int) -> None:
    canary = tmp_path / "canary"
    text = _texts(canary)[index]
    # CPU time of this thread, not wall time: a DoS text (9**9**9, 'a' * 10**9) would burn
    # seconds to minutes of it, a refusal takes ~ms; wall time also counted the other jobs
    # sharing a loaded 2-core machine (a wall-clock bound in the fast tier).
    t0 = time.thread_time()
    with pytest.raises(ScenarioError) as info:
        scenario_from_dict({"attack": {"signal": text}})
    elapsed = time.thread_time() - t0
    assert info.value.key == "attack.signal"
    assert "\n" not in str(info.value)
    assert str(info.value).startswith("attack.signal: ")
    assert not canary.exists(), "an expression executed code"
    assert elapsed < 0.5, f"refusing {text[:40]!r} took {elapsed:.2f} s of CPU"


@pytest.mark.parametrize("index", range(len(HOSTILE)))
@pytest.mark.parametrize("where", ["s", "sigma"])
def test_hostile_path_expression_is_refused_naming_the_field(tmp_path: Path, index: int,
                                                             where: str) -> None:
    canary = tmp_path / "canary"
    text = _texts(canary)[index].replace("t", "x") if where == "s" else _texts(canary)[index]
    good = {"s": ["y - cos(x)", "z - 8 + 4*cos(x)"], "sigma": ["t", "cos(t)", "8 - 4*cos(t)"]}
    good[where][1] = text
    sc = scenario_from_dict({"path": {"kind": "expr", **good}})
    with pytest.raises(ScenarioError) as info:
        scenario_path(sc)
    assert info.value.key == f"path.{where}[1]", str(info.value)
    assert "\n" not in str(info.value)
    assert not canary.exists(), "an expression executed code"


@pytest.mark.parametrize(("text", "words"), [
    ("__import__('os')", "unknown function '__import__'"),
    ("().__class__", "Attribute is not allowed"),
    ("lambda: 1", "Lambda is not allowed"),
    ("[t for t in (1,)]", "ListComp is not allowed"),
    ("t[0]", "Subscript is not allowed"),
    ("f'{t}'", "JoinedStr is not allowed"),
    ("(y := 1)", "NamedExpr is not allowed"),
    ("max(*t)", "Starred is not allowed"),
    ("sin(x=t)", "keyword arguments are not allowed"),
    ("9**9**9", "cannot be evaluated"),
    ("1e999", "too large"),
    ("1" + "0" * 400, "too large"),
    ("'a' * 10**9", "only numbers"),
    ("q + 1", "unknown name 'q' (variables allowed here: t)"),
    ("t" + "+t" * 400, "too complex"),
    ("(" * 300 + "t" + ")" * 300, "syntax error"),
], ids=lambda v: v[:30] if isinstance(v, str) else None)
def test_errors_say_what_is_wrong(text: str, words: str) -> None:
    with pytest.raises(ExprError) as info:
        compile_expr(text, ("t",), field="attack.signal")
    assert words in info.value.message
    assert info.value.field == "attack.signal"


@pytest.mark.parametrize(("text", "value"), [
    ("0.1*t + sin(z)", 0.1 * 0.5 + 0.479425538604203),
    ("clip(2*t, 0, 8)", 1.0), ("max(t, tau) - min(x, y)", 0.0), ("-t**2", -0.25),
    ("step(t - 1)", 0.0), ("pi*e", 8.539734222673566), ("2**-1", 0.5),
])
def test_ordinary_expressions_still_compile_and_evaluate(text: str, value: float) -> None:
    expr = compile_expr(text, ("t", "tau", "x", "y", "z"), field="attack.signal")
    assert expr(dict.fromkeys(("t", "tau", "x", "y", "z"), 0.5)) == pytest.approx(value)


def test_undefined_at_some_points_is_allowed_but_fails_softly_at_run_time() -> None:
    """``log(t - 1)`` is a fine signal for t > 1; at t = 0.5 it raises ValueError, which the
    attacker turns into a recorded non-finite sample (tfl_mav.sitl.attacker), not a crash."""
    expr = compile_expr("log(t - 1)", ("t",), field="attack.signal")
    with pytest.raises(ValueError):
        expr({"t": 0.5})
    assert expr({"t": 3.0}) == pytest.approx(0.6931471805599453)
