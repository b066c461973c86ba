"""Pictures of the world for people (not for the models): a perspective view with the arm visible."""

from __future__ import annotations

import numpy as np
import pybullet as p

from tvf.sim.world import World

VIEW_EYE = (1.25, 0.0, 0.8)
VIEW_TARGET = (0.42, 0.0, 0.0)


def perspective_view(world: World, width: int = 640, height: int = 480) -> np.ndarray:
    """An oblique RGB view of the whole scene, arm included, as uint8 (height, width, 3)."""
    view = p.computeViewMatrix(VIEW_EYE, VIEW_TARGET, [0, 0, 1], physicsClientId=world.client)
    proj = p.computeProjectionMatrixFOV(50, width / height, 0.05, 5.0, physicsClientId=world.client)
    _, _, rgba, _, _ = p.getCameraImage(
        width, height, view, proj, shadow=1, renderer=p.ER_TINY_RENDERER,
        flags=p.ER_NO_SEGMENTATION_MASK, physicsClientId=world.client,
    )  # fmt: skip
    return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3]
