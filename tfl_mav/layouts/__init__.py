"""Foxglove layouts for the flight logs (``tfl-mav.json``: open a run's MCAP file with it)."""
