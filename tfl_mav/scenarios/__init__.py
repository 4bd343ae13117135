"""Built-in scenarios, addressable by name (``tfl-mav offline paper``)."""
