"""The one accelerator seam: pure float functions translated to C mechanically and built with the
system compiler."""
