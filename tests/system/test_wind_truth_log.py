"""A SITL flight in moving air records the wind in its truth log: ``/sim/truth/wind``
(``tfl_mav.TruthWind``) beside every ``/sim/truth/state``, read back with the mcap reader
and the protobuf library from the schema stored in the file, and equal — bit for bit — to
the seeded wind field the offline log keeps; a flight in still air has no such channel."""

from __future__ import annotations

from pathlib import Path

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from tfl_mav.scenario import apply_overrides, load_scenario
from tfl_mav.sitl.wind import WindField
from tfl_mav.tools.harness.demo import run_demo

_WIND = ["wind.mean_mps=[2.0, -1.0, 0.0]", "wind.turbulence=light",
         "wind.gust_mps=[0.0, 3.0, 0.0]", "wind.gust_start_s=0.3", "wind.gust_duration_s=0.4"]


def _messages(path: Path) -> dict[str, list[dict]]:
    """Every ``/sim/truth/*`` message of the file by topic, decoded (protobuf) from the
    file's own schemas."""
    out: dict[str, list[dict]] = {}
    classes = {}
    with open(path, "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages(log_time_order=False):
            if not channel.topic.startswith("/sim/truth/"):
                continue
            cls = classes.get(schema.id)
            if cls is None:
                pool = descriptor_pool.DescriptorPool()
                for fd in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                    pool.Add(fd)
                cls = classes[schema.id] = message_factory.GetMessageClass(
                    pool.FindMessageTypeByName(schema.name))
            msg = cls.FromString(m.data)
            out.setdefault(channel.topic, []).append(
                {f.name: (v if isinstance(v, (int, float)) else list(v))
                 for f, v in msg.ListFields()} | {"_schema": schema.name})
    return out


@pytest.mark.slow
def test_the_truth_log_holds_the_wind_the_offline_log_does(tmp_path):
    sc = apply_overrides(load_scenario("paper"), _WIND)
    run_demo("paper", tmp_path, settings=_WIND, duration_s=1.0, plots=False, scenario=sc)
    msgs = _messages(tmp_path / "run.mcap")
    wind, state = msgs["/sim/truth/wind"], msgs["/sim/truth/state"]
    assert {m["_schema"] for m in wind} == {"tfl_mav.TruthWind"}
    assert [m["t_s"] for m in wind] == [m["t_s"] for m in state]   # one per truth tick
    assert len(wind) >= 900                                         # 1 s at 1 kHz
    h = 1.0 / sc.run.physics_hz
    field = WindField(sc.wind, sc.run.seed, h)
    for m in wind:
        assert tuple(m["wind_mps"]) == field.at(round(m["t_s"] / h))
    # the gust is in it: 3 m/s across at its middle, on top of the mean and turbulence
    mid = min(wind, key=lambda m: abs(m["t_s"] - 0.5))
    calm = apply_overrides(sc, ["wind.gust_duration_s=0.0"])
    assert mid["wind_mps"][1] - WindField(calm.wind, sc.run.seed, h).at(
        round(mid["t_s"] / h))[1] == pytest.approx(3.0, abs=1e-9)


@pytest.mark.slow
def test_still_air_has_no_wind_channel(tmp_path):
    run_demo("paper", tmp_path, duration_s=0.2, plots=False)
    msgs = _messages(tmp_path / "run.mcap")
    assert "/sim/truth/state" in msgs and "/sim/truth/wind" not in msgs
