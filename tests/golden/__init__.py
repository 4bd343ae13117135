"""Golden flights: digests of whole trajectories and commands that refactors must leave
unchanged."""
