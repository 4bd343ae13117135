"""``tfl-mav envelope`` end to end on a two-case spec of short flights (real flights)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tfl_mav.tools.cli.main import main
from tfl_mav.tools.harness.envelope.results import read_results_file, write_results_file

SPEC = """
[[family]]
name = "tiny"
title = "two short flights"
base = "paper"
duration_s = 2.0

[[family.case]]
name = "tiny-paper"

[[family.case]]
name = "tiny-dead"
set = ["attack.signal=off"]
"""


@pytest.fixture
def tiny(tmp_path: Path) -> tuple[list[str], Path]:
    spec = tmp_path / "cases.toml"
    spec.write_text(SPEC, encoding="utf-8")
    baseline = tmp_path / "baseline.json"
    return ["envelope", "--spec", str(spec), "--baseline", str(baseline), "--jobs", "2"], \
        baseline


def test_rewrite_then_compare_then_a_regression_exits_1(
        tiny: tuple[list[str], Path], capsys: pytest.CaptureFixture[str]) -> None:
    args, baseline = tiny
    assert main([*args, "--rewrite-baseline"]) == 0
    out = capsys.readouterr()
    assert "tiny-paper" in out.out and "— →" in out.out      # before/after: new cases
    assert "[2/2]" in out.err                                 # progress on stderr
    rf = read_results_file(baseline)
    assert set(rf.results) == {"tiny-paper", "tiny-dead"}

    assert main([*args, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["regressions"] == []
    assert {c["verdict"] for c in report["cases"]} == {"same"}

    # a baseline that flew the paper case 20 % closer: today is a regression
    b = rf.results["tiny-paper"]
    b.max_distance_m = b.max_distance_m / 1.2
    write_results_file(baseline, rf)
    assert main([*args, "--only", "tiny-p*"]) == 1
    out = capsys.readouterr().out
    assert "WORSE: max distance" in out and "regressed: tiny-paper" in out


def test_markdown_writes_the_readme_block(tiny: tuple[list[str], Path], tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    args, _baseline = tiny
    assert main([*args, "--markdown"]) == 2                   # no baseline yet
    assert "fly --rewrite-baseline first" in capsys.readouterr().err
    assert main([*args, "--rewrite-baseline", "--only", "tiny-dead"]) == 0
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- envelope:begin -->\nold\n<!-- envelope:end -->\nend\n")
    (tmp_path / "docs").mkdir()
    doc = tmp_path / "docs" / "envelope.md"
    doc.write_text("# doc\n<!-- envelope:begin -->\nold\n<!-- envelope:end -->\n")
    capsys.readouterr()
    assert main([*args, "--markdown", "--write-readme", "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert "old" not in text and text.startswith("intro\n") and text.endswith("end\n")
    assert "| two short flights | 2 |" in text and "tiny-dead" not in text
    assert "tiny-dead" in doc.read_text() and "old" not in doc.read_text()


def test_a_bad_spec_is_one_line_and_exit_2(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    spec = tmp_path / "bad.toml"
    spec.write_text(SPEC.replace('"attack.signal=off"', '"attack.signal=offf"'))
    assert main(["envelope", "--spec", str(spec)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("tfl-mav envelope: spec error: ") and "tiny-dead" in err
    assert "\n" not in err
