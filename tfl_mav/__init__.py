"""tfl-mav: attack-resilient quadrotor path following over MAVLink.

Subpackages: ``control`` (pure math: jets, paths, the TFL law, attack detection),
``mavlink`` (UDP link, NED/ENU frames, MCAP recorder); ``scenario`` and ``expr`` are
shared by the simulator (``sitl``) and the controller daemon.
"""

__version__ = "0.1.0"
