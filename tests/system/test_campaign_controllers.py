"""Campaigns sweeping ``controller``: the baselines fly beside TFL in one table.

Real flights of 2 s (sim time; ~0.1-0.3 s of CPU each). ``success_max_distance_m`` is loose:
a 2 s flight has not converged, which is not what these tests are about.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from tfl_mav.tools.cli.main import main
from tfl_mav.tools.harness.campaign import load_spec, run_campaign
from tfl_mav.tools.harness.campaign.results import format_value, parse_value, read_results
from tfl_mav.tools.harness.campaign.run import execute

GRID = """
name = "ctl"
base = "paper"
duration_s = 2.0
success_max_distance_m = 10.0
[grid]
controller = ["tfl", "se3"]
"attack.rotor" = [0, 2]
[report]
maps = [["controller", "attack.rotor"]]
"""

FAILING = '''
class Raises:
    def reset(self, scenario):
        pass

    def update(self, t_s, state, rpm):
        if t_s >= 0.05:
            raise RuntimeError("gain table missing")
        return [2.7] * 4


class NaNs:
    def reset(self, scenario):
        pass

    def update(self, t_s, state, rpm):
        return [float("nan")] * 4
'''


def _spec(tmp_path: Path, text: str, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_a_controller_grid_gives_rows_for_each_with_its_column(tmp_path: Path) -> None:
    spec = load_spec(_spec(tmp_path, GRID))
    assert spec.columns == ["controller", "attack.rotor"]
    runs = spec.runs()
    assert [(r.controller, r.values) for r in runs] == [
        ("tfl", {"controller": "tfl", "attack.rotor": 0}),
        ("tfl", {"controller": "tfl", "attack.rotor": 2}),
        ("se3", {"controller": "se3", "attack.rotor": 0}),
        ("se3", {"controller": "se3", "attack.rotor": 2})]
    assert not any("controller=" in s for r in runs for s in r.settings)   # not a --set

    out = tmp_path / "c"
    summary = run_campaign(spec, out, workers=2, progress=False)
    header, rows = read_results(out / "results.csv")
    assert header[:4] == ["run_id", "controller", "attack.rotor", "seed"]
    by = {(r["controller"], r["attack.rotor"]): r for r in rows}
    assert set(by) == {("tfl", 0), ("tfl", 2), ("se3", 0), ("se3", 2)}
    assert summary["runs"] == 4
    # TFL holds the paper attack; SE(3) with a standard allocation flips at once
    assert by[("tfl", 2)]["success"] is True and by[("tfl", 2)]["detected_rotor"] == 2
    assert by[("se3", 2)]["crashed"] is True
    assert by[("se3", 2)]["reason"].startswith("crashed: ")
    assert by[("se3", 2)]["detected_rotor"] == 2          # found from rpm, as for TFL
    assert by[("se3", 0)]["success"] is True and by[("se3", 0)]["sim_time_s"] > 1.9

    # the tfl rows are the plain (controller-less) run's, number for number (as the table
    # keeps them: "" reads back as None)
    tfl_run = next(r for r in runs if r.values == {"controller": "tfl", "attack.rotor": 2})
    without = load_spec(_spec(tmp_path, GRID.replace('controller = ["tfl", "se3"]\n', "")
                              .replace('maps = [["controller", "attack.rotor"]]', ""),
                              "plain.toml")).runs()
    assert without[1].settings == tfl_run.settings and without[1].controller == "tfl"
    plain = execute(without[1])
    for key, value in plain.items():
        if key != "wall_time_s":
            assert by[("tfl", 2)][key] == parse_value(format_value(value)), key

    assert "### controller" in (out / "report.md").read_text()
    png = out / "map_controller__rotor.png"
    assert png.stat().st_size > 10_000


def test_without_the_key_the_table_has_no_controller_column(tmp_path: Path) -> None:
    spec = load_spec(_spec(tmp_path, 'duration_s = 0.5\n[grid]\n"attack.rotor" = [1]\n'))
    assert spec.columns == ["attack.rotor"] and spec.runs()[0].controller == "tfl"
    fixed = load_spec(_spec(tmp_path, 'duration_s = 0.5\n[set]\ncontroller = "se3"\n'
                                      '[grid]\n"attack.rotor" = [1]\n', "f.toml"))
    assert fixed.columns == ["attack.rotor"] and fixed.runs()[0].controller == "se3"


@pytest.mark.parametrize(("text", "key", "words"), [
    ('[grid]\ncontroller = ["tfl", "pid9"]\n', "grid.controller", "unknown controller 'pid9'"),
    ('[[variants]]\nname = "a"\ncontroller = "nope.py:X"\n', "variants[0].controller",
     "cannot import"),
    ('mode = "mavlink"\n[grid]\ncontroller = ["tfl", "se3"]\n', "grid.controller",
     'needs mode = "offline"'),
])
def test_a_bad_controller_is_one_line_and_exit_2(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 text: str, key: str, words: str) -> None:
    spec = _spec(tmp_path, 'name = "bad"\nduration_s = 2.0\n' + text)
    assert main(["campaign", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"tfl-mav campaign: spec error: {key}: ") and words in err, err
    assert not (tmp_path / "out").exists()          # nothing ran


def test_a_failing_controller_fails_its_row_and_the_others_fly(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text(FAILING, encoding="utf-8")
    raises, nans = f"{bad}:Raises", f"{bad}:NaNs"
    spec = load_spec(_spec(tmp_path, GRID.replace('["tfl", "se3"]',
                                                  f'["tfl", "{raises}", "{nans}"]')
                           .replace("[0, 2]", "[0]")))
    out = tmp_path / "c"
    summary = run_campaign(spec, out, workers=2, progress=False)
    assert summary["runs"] == 3 and summary["succeeded"] == 1
    with (out / "results.csv").open(encoding="utf-8") as f:
        by = {r["controller"]: r for r in csv.DictReader(f)}
    assert by["tfl"]["success"] == "true" and by["tfl"]["reason"] == ""
    assert by[raises]["success"] == "false" and by[raises]["crashed"] == "false"
    assert by[raises]["reason"] == (f"{raises} failed at t = 0.050 s: raised RuntimeError: "
                                    "gain table missing")
    assert by[nans]["reason"] == (f"{nans} failed at t = 0.000 s: returned a non-finite "
                                  "thrust for rotor 1 (nan)")
    assert "gain table missing" in (out / "report.md").read_text()
