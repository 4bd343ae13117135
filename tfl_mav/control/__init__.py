"""Pure control math: no sockets, no files, no clocks."""
