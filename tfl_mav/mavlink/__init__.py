"""MAVLink plumbing shared by the simulator and the controller: link, frames, recorder."""
