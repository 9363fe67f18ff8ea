"""PyBullet simulation: a world per process, bodies with joints by name, the RG2 gripper."""
