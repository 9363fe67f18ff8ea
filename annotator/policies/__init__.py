"""Clutter-removal policies behind one interface (docs/learning.md).

- :mod:`~annotator.policies.records`: what a vision policy sees (:class:`Observation`) and
  answers (:class:`Grasps`);
- :mod:`~annotator.policies.oracle`: ``labels`` and ``random``, which see the true scene;
- :mod:`~annotator.policies.vision`: ``vision-random``, antipodal pairs on the observed cloud;
- :mod:`~annotator.policies.predictions`: a learner's predictions file;
- :mod:`~annotator.policies.loop` and :mod:`~annotator.policies.resolve`: a callable in the loop,
  and ``--policy NAME`` to the policy.
"""

from annotator.policies.records import CameraImage, Grasp, Grasps, Observation, PolicyError, Proposal

__all__ = ["CameraImage", "Grasp", "Grasps", "Observation", "PolicyError", "Proposal"]
