"""Command-line tools around a flight (the ``tfl-mav`` entry point)."""
