"""Unit tests: one module's behaviour, in process, no sockets, no subprocesses, no closed-loop
flights over the link."""
