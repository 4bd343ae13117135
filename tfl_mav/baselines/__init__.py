"""Baseline controllers to fly beside the TFL law, through the public
:class:`~tfl_mav.api.Controller` protocol: a geometric tracking controller on SE(3)
(:mod:`~tfl_mav.baselines.se3`) and a PX4-style cascade (:mod:`~tfl_mav.baselines.cascade`).

Both fly the path through the same path-to-reference code (:mod:`~tfl_mav.baselines.
reference`) and the controller's own (wrong on purpose) model of the vehicle, the one the
TFL law gets (:func:`~tfl_mav.from_scenario.model_params`), so a difference between them is
the law's.
"""
