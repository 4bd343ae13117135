"""Putting a simulator and a controller together.

Offline flights, the lockstep pilot, process launching, free ports: the library that the
CLI (``tools``), the tests and the benchmarks share.
"""
