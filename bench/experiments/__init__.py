"""One-off experiments: each was run to decide a constant or a design, and the decision record that
cites it keeps its figures. They run as ``python -m bench.experiments.NAME`` and write records like
the standing benchmarks, but nothing re-runs them to track the product."""
