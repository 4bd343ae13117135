"""Attack detection, isolation and estimation from ESC rpm."""
