"""The seed's robot cell: the table, the UR3 on its mount and the Kinect v2, defined once.

``annotator.cell.world`` loads them into a world (the seed scene, replay, rendering and, later,
the trials of ``annotate --cell`` all use it); ``annotator.cell.kinect`` renders Kinect v2 views.
"""

from annotator.cell.world import Cell, TableTop, build_cell, kinect_pose, robot_mount_pose

__all__ = ["Cell", "TableTop", "build_cell", "kinect_pose", "robot_mount_pose"]
