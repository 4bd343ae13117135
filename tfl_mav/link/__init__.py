"""MAVLink 2 transport: UDP link with peer pinning, signing, the dialect, payload decoding.

Knows nothing of TFL."""
