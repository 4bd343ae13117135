"""The vehicle's model shared by every part: the state, frames, rotations, the airframe, the flight
modes."""
