"""rg2-annotator: batch grasp annotation for a UR3 + OnRobot RG2 in PyBullet.

Importing the package imports no simulator: :mod:`annotator.dataset` (reading labels) works
without pybullet; :mod:`annotator.sim` imports it (quietly) for everything that simulates.
"""

__version__ = "0.1.0"
