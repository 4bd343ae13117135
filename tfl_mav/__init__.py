"""tfl-mav: attack-resilient quadrotor path following over MAVLink.

Subpackages: ``control`` (pure math: jets, paths, the TFL law, attack detection),
``mavlink`` (UDP link, NED/ENU frames, MCAP recorder); ``scenario`` and ``expr`` are
shared by the simulator (``sitl``) and the controller daemon.
"""

import os as _os

__version__ = "0.1.0"

# One BLAS thread unless the user chose otherwise. Every matrix here is tiny (≤ 8×8: the
# recovery law's LQR design, tfl_mav/control/safe/lqr.py); OpenBLAS's thread pool only
# adds wake-ups, and on a busy 2-core machine a 4×4 DARE took 35 ms instead of 1 ms
# (bench/bench_controller.py). Effective only if numpy is not imported yet (the CLI, the
# simulator and daemon processes); the numbers do not depend on it at these sizes.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
