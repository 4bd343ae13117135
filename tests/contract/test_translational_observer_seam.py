"""With the translational disturbance observer on (a scenario outdoors), the seam's compiled
step still flies the Python step's bits: on random states, and over a whole windy flight."""

from __future__ import annotations

import random

import numpy as np

from tests.contract.test_compiled import PATHS
from tests.contract.test_step import random_state
from tfl_mav.control.path.paths import build_path
from tfl_mav.control.tfl.tfl_controller import TFLController, as_state
from tfl_mav.from_scenario import law_config, model_params
from tfl_mav.model.state import State
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import load_scenario

_WINDY = load_scenario("paper").replace(**{"wind.mean_mps": [3.0, 1.0, 0.0],
                                           "wind.turbulence": "light",
                                           "vehicle.rotor_aero": True})   # the vertical too


def _leaves(x) -> list[str]:
    """Every number of a nested state as its repr (a list or a tuple: the same leaves)."""
    if isinstance(x, (tuple, list)):
        return [leaf for v in x for leaf in _leaves(v)]
    return [repr(float(x))]


def _law(monkeypatch, mode: str) -> TFLController:
    monkeypatch.setenv("TFL_MAV_NATIVE", mode)
    kind, params, _y0 = PATHS["paper"]
    cfg = law_config(_WINDY)
    assert cfg.translational_observer and cfg.translational_observer_vertical
    return TFLController(model_params(_WINDY), build_path(kind, params), cfg, 0.001)


def test_compiled_step_with_the_observer_is_the_python_step(monkeypatch):
    py, c = _law(monkeypatch, "off"), _law(monkeypatch, "sync")
    assert py.core == "python" and c.core == "compiled"
    rng = random.Random(5)
    for trial in range(30):
        rotor = (0, 0, 2, 3)[trial % 4]
        for ctrl in (py, c):
            ctrl.set_attack(rotor, 1.0 if rotor else 0.0)
        st = random_state(rng, PATHS["paper"][2])
        for tick in range(5):       # the observer needs a tick before it reads an acceleration
            if tick:
                st = State(tuple(p + 1e-3 * v for p, v in zip(st.position_m, st.velocity_mps,
                                                              strict=True)),
                           tuple(v + 1e-3 * rng.uniform(-2, 2) for v in st.velocity_mps),
                           st.quaternion_wxyz, st.body_rates_radps)
            assert repr(py.update(st)) == repr(c.update(st))
            assert _leaves(py.state) == _leaves(c.state)
    d = as_state(c.state).tdob
    assert d.has_prev == 1.0 and 0.0 not in (d.d_x, d.d_y, d.d_z)   # it did estimate


def test_a_windy_flight_is_bit_identical_compiled_and_python(monkeypatch):
    sc = _WINDY.replace(**{"run.duration_s": 2.0})
    monkeypatch.setenv("TFL_MAV_NATIVE", "off")
    py = fly_offline(sc)
    monkeypatch.setenv("TFL_MAV_NATIVE", "sync")
    c = fly_offline(sc)
    assert np.array_equal(py["position_m"], c["position_m"])
    assert np.array_equal(py["thrust_cmd_n"], c["thrust_cmd_n"])
