"""The flight envelope: a checked-in spec of offline flights, its baseline, and the guard.

:mod:`~tfl_mav.tools.harness.envelope.spec` (``cases.toml`` → cases),
:mod:`~tfl_mav.tools.harness.envelope.run` (fly them in a pool),
:mod:`~tfl_mav.tools.harness.envelope.results` (a result, its outcome, the JSON files),
:mod:`~tfl_mav.tools.harness.envelope.regression` (the rule that fails a case),
:mod:`~tfl_mav.tools.harness.envelope.reference` (the same spec flown by another tree's CLI),
:mod:`~tfl_mav.tools.harness.envelope.laws` (each case flown by the supervisor, TFL alone and the
safe law alone, and the verdict) and :mod:`~tfl_mav.tools.harness.envelope.report` (the tables
and the README block). The command is
``tfl-mav envelope``; the test tier is ``python -m pytest -m envelope``.
"""
