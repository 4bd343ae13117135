"""The tools around a flight (import name ``tfl_mav.tools``; the directory ``tools/``): the
``tfl-mav`` command line (:mod:`tfl_mav.tools.cli`) and the harness that puts a vehicle and a
controller together — demo, campaigns, the envelope tier, the lockstep pilot, fault relays."""
