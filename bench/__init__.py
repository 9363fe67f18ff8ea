"""rg2-annotator's benchmarks: ``python -m bench.NAME`` from the repository's root.

Each benchmark prints its figures and writes one JSON record through :class:`bench.harness.Run`
under ``bench/results/``; ``python -m bench.docs`` makes ``docs/performance.md`` from the newest
record of each. The index is ``bench/README.md``.
"""
