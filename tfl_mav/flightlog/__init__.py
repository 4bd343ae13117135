"""The flight log: MCAP recorder, Foxglove schemas, reading logs back, summaries, plots."""
