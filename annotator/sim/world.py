"""One PyBullet physics client and its simulation settings; snapshots for cheap trial resets."""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator

import pybullet as pb

from annotator.config import PhysicsConfig

log = logging.getLogger(__name__)

# Bodies are moved this far apart (m) to drop their contact pairs when a snapshot is restored:
# far beyond any object or robot extent, small enough that float32 AABBs stay exact to ~0.1 mm.
SCATTER_DISTANCE = 100.0


@contextlib.contextmanager
def private_client() -> Iterator[int]:
    """A physics client of its own (DIRECT, PyBullet's defaults: nothing configured) to read a
    model in, disconnected after the block."""
    client = pb.connect(pb.DIRECT)
    try:
        yield client
    finally:
        pb.disconnect(physicsClientId=client)


class World:
    """Owns a PyBullet client (DIRECT by default). Everything else receives ``world.client``."""

    def __init__(self, physics: PhysicsConfig | None = None, *, gui: bool = False) -> None:
        self.physics = physics or PhysicsConfig()
        self.client = pb.connect(pb.GUI if gui else pb.DIRECT)
        if self.client < 0:
            raise RuntimeError("could not connect to PyBullet" + (" (GUI needs a display)" if gui else ""))
        self.steps = 0  # simulated steps since creation, for statistics
        self.step_seconds = 0.0  # wall time spent inside stepSimulation, for statistics
        self.gravity_on = True
        # called before every stepSimulation (external forces last one step): a trial's load
        # that is not in the bodies' models (GraspTrial: a moved centre of mass); None: nothing
        self.before_step: Callable[[], None] | None = None
        self.configure()

    def configure(self) -> None:
        """Apply the physics settings (time step, solver iterations, gravity)."""
        pb.setPhysicsEngineParameter(
            fixedTimeStep=self.physics.time_step,
            numSolverIterations=self.physics.solver_iterations,
            numNonContactInnerIterations=self.physics.non_contact_iterations,
            contactERP=self.physics.contact_erp,
            contactBreakingThreshold=self.physics.contact_breaking_threshold,
            # Sorted broadphase pairs: without it a trial's result depended on which trials the
            # worker ran before (8 of 30 differed when run in reverse order), so labels would
            # have depended on --workers.
            deterministicOverlappingPairs=1,
            physicsClientId=self.client,
        )
        pb.setGravity(0, 0, self.physics.gravity, physicsClientId=self.client)

    def use(self, physics: PhysicsConfig) -> None:
        """Step with ``physics`` from now on (nothing to do if it is the current one); gravity stays
        as it is."""
        if physics == self.physics:
            return
        self.physics = physics
        self.configure()
        self.set_gravity(self.gravity_on)

    @property
    def dt(self) -> float:
        """The time step (s) of one ``step()``."""
        return self.physics.time_step

    def set_gravity(self, on: bool) -> None:
        """Gravity along world -z (``physics.gravity``, m/s^2) when ``on``, none otherwise."""
        pb.setGravity(0, 0, self.physics.gravity if on else 0.0, physicsClientId=self.client)
        self.gravity_on = on

    def step(self, n: int = 1) -> None:
        """Advance the simulation ``n`` steps of ``dt`` seconds; the wall time inside is counted."""
        t0 = time.perf_counter()
        before = self.before_step
        for _ in range(n):
            if before is not None:
                before()
            pb.stepSimulation(physicsClientId=self.client)
        self.step_seconds += time.perf_counter() - t0
        self.steps += n

    def step_while_open(self) -> bool:
        """One step of a GUI world; False once its window is closed (the client is gone)."""
        try:
            pb.stepSimulation(physicsClientId=self.client)
        except pb.error:
            return False
        return True

    def save_state(self) -> int:
        """Snapshot every body of the world; returns the id :meth:`restore_state` takes."""
        return pb.saveState(physicsClientId=self.client)

    def restore_state(self, state_id: int) -> None:
        """Return to snapshot ``state_id`` with no memory of earlier contacts.

        ``restoreState`` resets poses, velocities and joint states, but not Bullet's persistent
        contact manifolds, whose cached impulses warm-start the solver on the next step: a trial
        then depended on the trial before it (the same 10 candidates run twice in one world gave
        3 different rows of 10). So the bodies are first scattered far apart, one collision pass
        releases every pair (and its manifold), and the snapshot is restored again; the next
        step finds its contacts afresh, exactly as in a new world.

        The contact breaking threshold is set again first: PyBullet keeps one for all the clients
        of a process (gContactBreakingThreshold, read when a pair's manifold is made), so another
        world configured since this one would otherwise decide this world's contacts.
        """
        client = self.client
        pb.setPhysicsEngineParameter(
            contactBreakingThreshold=self.physics.contact_breaking_threshold, physicsClientId=client
        )
        pb.restoreState(stateId=state_id, physicsClientId=client)
        for i in range(pb.getNumBodies(physicsClientId=client)):
            uid = pb.getBodyUniqueId(i, physicsClientId=client)
            far = [SCATTER_DISTANCE * (i + 1), 0.0, 0.0]
            pb.resetBasePositionAndOrientation(uid, far, [0.0, 0.0, 0.0, 1.0], physicsClientId=client)
        pb.performCollisionDetection(physicsClientId=client)
        pb.restoreState(stateId=state_id, physicsClientId=client)

    def remove_state(self, state_id: int) -> None:
        """Forget snapshot ``state_id``."""
        pb.removeState(state_id, physicsClientId=self.client)

    def remove_body(self, uid: int) -> None:
        """Remove body ``uid`` from the world."""
        pb.removeBody(uid, physicsClientId=self.client)

    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if self.client >= 0 and pb.isConnected(physicsClientId=self.client):
            pb.disconnect(physicsClientId=self.client)
        self.client = -1

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
