"""Built-in campaign specs, addressable by name (``tfl-mav campaign paper-envelope``)."""
