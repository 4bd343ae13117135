"""The simulated vehicle: rigid-body physics, motors/ESCs, attacker, MAVLink endpoint."""
