"""The tools researchers reach for after ``annotate``: replay on the arm, pictures, a report,
exports, evaluation of given grasps, calibration against real trials.

Each module is a library first (functions with typed results) and a thin click command second
(in :mod:`annotator.cli`, one module per command).
"""
