"""Keyed random generators: each draw depends only on its keys, never on process, order or history.

Python's ``hash()`` is salted per process, so a key is turned into a seed through SHA-256 of its
text. Every random choice of the tool (candidates, perturbed trials, cell placements, views, picture
sheets, dataset helpers) draws from one of these, so labels are bit-identical whatever worker,
order of work or machine computes them.
"""

from __future__ import annotations

import hashlib

import numpy as np


def keyed_rng(*keys: object) -> np.random.Generator:
    """A PCG64 Generator seeded by SHA-256 of ``"\\x00".join(str(k) for k in keys)``."""
    digest = hashlib.sha256("\x00".join(str(k) for k in keys).encode()).digest()
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(np.frombuffer(digest, "<u4").tolist())))


def object_rng(seed: int, object_id: str) -> np.random.Generator:
    """The object's candidate Generator: depends only on ``(seed, object_id)``."""
    return keyed_rng(int(seed), object_id)


def trial_rng(seed: int, object_id: str, grasp_id: int) -> np.random.Generator:
    """A candidate's Generator for its perturbed trials: depends on (seed, object, grasp) only."""
    return keyed_rng("robust", int(seed), object_id, int(grasp_id))
