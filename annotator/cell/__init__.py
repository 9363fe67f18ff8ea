"""The seed's robot cell: the table, the UR3 on its mount and the Kinect v2, defined once.

``annotator.cell.world`` loads them into a world (the seed scene, replay, rendering, the trials of
``annotate --cell`` and the scenes all use it); ``annotator.cell.kinect`` renders Kinect v2 views;
``reach`` checks the arm's reach along an approach (closed-form IK), ``execute`` runs a reachable
grasp on the arm (approach, close, lift, judge: ``annotator replay`` and clutter removal),
``placement`` and ``resting`` put objects on the table, ``candidates`` and ``batch`` make and
label a cell run's grasps, ``views`` its depth views, ``mount`` the UR3 + gripper model.
"""

from annotator.cell.world import Cell, TableTop, build_cell, kinect_pose, robot_mount_pose

__all__ = ["Cell", "TableTop", "build_cell", "kinect_pose", "robot_mount_pose"]
