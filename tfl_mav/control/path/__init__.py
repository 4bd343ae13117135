"""Paths (paper §IV) and the path tracker: σ, s, the virtual output on jets, and the code generated
from them per path."""
