"""The offboard controller: the flight computer's one tick, the daemon around it, flight software
that is not ours."""
