"""Contract tests: two forms of one thing agree bit for bit (a compiled core and its Python, our
codec and pymavlink, a fast reader and the library's)."""
