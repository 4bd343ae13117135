"""The safe law and when it flies: the reduced-attitude law, its three-rotor step, LQR, authority
and take-over tests."""
