"""tfl-mav: attack-resilient quadrotor path following over MAVLink.

One import name over three directories (docs/design.md, "Rooms"): ``tfl_mav/`` the
controller side (``control``: the laws and the detector; ``controller``: the flight computer
and its daemon; ``link``, ``flightlog``, ``model``, ``accel``) and the public face (``api``,
``offline``); ``sitl/`` the simulated vehicle, imported as ``tfl_mav.sitl``; ``tools/`` the
harness and the command line, imported as ``tfl_mav.tools``. ``scenario`` and ``expr`` are
shared by the vehicle and the controller.
"""

import os as _os

__version__ = "0.1.0"

# One BLAS thread unless the user chose otherwise. Every matrix here is tiny (≤ 8×8: the
# recovery law's LQR design, tfl_mav/control/safe/lqr.py); OpenBLAS's thread pool only
# adds wake-ups, and on a busy 2-core machine a 4×4 DARE took 35 ms instead of 1 ms
# (bench/bench_controller.py). Effective only if numpy is not imported yet (the CLI, the
# simulator and daemon processes); the numbers do not depend on it at these sizes.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
