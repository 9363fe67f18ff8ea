"""rg2-annotator: batch grasp annotation for a UR3 + OnRobot RG2 in PyBullet."""

__version__ = "0.1.0"
