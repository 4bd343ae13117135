"""Relaxed hover with a rotor pinned high: the equilibria (:mod:`equilibrium`), the law as
one
pure step (:mod:`step`), its construction (:mod:`law`); flights in
:mod:`tfl_mav.tools.harness.spin`."""
