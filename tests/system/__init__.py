"""System tests: real parts put together: loopback UDP, `tfl-mav` subprocesses, recorded MCAP files
read back, closed-loop flights."""
