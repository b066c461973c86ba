"""The Python API: a planner that answers "what next?" from plain image arrays (no simulator needed).

    import tvf
    planner = tvf.load_planner("tvf-large")                  # the shipped lite weights
    decision = planner.next_action(color, height, goal_color, goal_height)

``color`` is the top-down colour image, uint8 (160, 160, 3); ``height`` the height map above the table in
metres, float32 (160, 160); both on the workspace grid of docs/conventions.md (row = y, col = x, 3.125 mm
pixels). The decision's poses are in the robot base frame: x, y, z in metres, yaw in radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvf.errors import TvfError
from tvf.geometry import WORKSPACE, world_to_pixel, yaw_to_bin
from tvf.planning.search import Plan
from tvf.policies.registry import LEARNED_METHODS, PLANNER_OPTIONS, PolicySpec, make_policy

__all__ = ["Decision", "Planner", "load_planner"]


@dataclass(frozen=True)
class Decision:
    """One pick-and-place: poses in the robot base frame and the pixels they came from."""

    pick: np.ndarray
    """(x, y, z, yaw) of the suction cup at the pick: the top of the block (yaw 0)."""
    place: np.ndarray
    """(x, y, z, yaw) at the place: z is one block above the surface, yaw the turn applied to the block."""
    pick_pixel: tuple[int, int]
    """(row, col) of the pick in the input image."""
    place_pixel: tuple[int, int]
    rotation_bin: int = 0
    """The place's rotation bin (of ``n_rotations``): the turn ``place yaw - pick yaw`` in image terms."""
    n_rotations: int = 36
    plan: Plan | None = None
    """The TVF search tree behind the decision (None for the GCTN)."""

    def as_array(self) -> np.ndarray:
        """The ``(2, 4)`` action the simulator and `TvfEnv.step` take."""
        return np.stack([self.pick, self.place])


class Planner:
    """A loaded method (GCTN or TVF) that plans one step at a time from images."""

    def __init__(self, method: str, policy) -> None:
        self.method = method
        self._policy = policy

    def next_action(
        self, color: np.ndarray, height: np.ndarray, goal_color: np.ndarray, goal_height: np.ndarray
    ) -> Decision:
        """The next pick and place that bring the scene of ``color``/``height`` towards the goal images."""
        obs = {"color": _color(color, "color"), "height": _height(height, "height")}
        goal = {"color": _color(goal_color, "goal_color"), "height": _height(goal_height, "goal_height")}
        chosen = self._policy.act(obs, goal)
        if chosen is None:
            raise TvfError(f"{self.method} found no action for this scene; check the input images")
        action = np.asarray(chosen, dtype=np.float64)
        pick_px, place_px = world_to_pixel(action[:, :2])
        n = self.n_rotations
        rotation = int(yaw_to_bin(action[1, 3] - action[0, 3], n))
        return Decision(action[0], action[1], _pair(pick_px), _pair(place_px), rotation, n,
                        getattr(self._policy, "last_plan", None))  # fmt: skip

    @property
    def n_rotations(self) -> int:
        """The rotation bins of the planner's GCTN (36: 10 degree steps)."""
        search = getattr(self._policy, "search", None)
        return int(search.n_rotations if search is not None else self._policy.model.preset.n_rotations)

    def __repr__(self) -> str:
        return f"Planner({self.method!r})"


def load_planner(
    method: str = "tvf-large", gctn: str | None = None, vf: str | None = None, device: str = "auto",
    keep_images: bool = False, turns: int | None = None, goal_mask: bool | None = None,
    mask_places: str | None = None, refine_yaw: bool | None = None, centred_share: float | None = None,
    centre_picks: bool | None = None, foresight: str | None = None, **planner,
) -> Planner:  # fmt: skip
    """A planner of ``method`` (gctn | tvf-small | tvf-large, or one of them with the paper's rules:
    gctn-paper | tvf-small-paper | tvf-large-paper, or without the image rules: gctn-no-image-rules |
    tvf-small-no-image-rules | tvf-large-no-image-rules) with the shipped weights, or a run folder, a
    ``.pt`` or a ``.safetensors`` file per model; ``planner`` overrides the search (k, depth, proposals,
    pick_branches, turns_depth, tie_band, root_k, order_branch, gamma, root_alpha, first_step_band,
    snap_heights, support_check, place_search, turn_search;
    docs/planner.md); ``keep_images`` keeps a TVF plan's imagined images; ``turns`` (1, 2, 4; 8 adds
    mirrors) averages the GCTN over quarter turns of the scene (default: the method's); ``goal_mask``
    True masks the GCTN's maps by the height difference to the goal (:mod:`tvf.models.goal_mask`;
    default: the method's),
    ``mask_places`` (gap, centred, bottom-up, ordered, layered, cells) narrows its places (default: the
    method's) and ``centred_share`` sets how near a region's middle the centred ones lie (default 0.9);
    ``refine_yaw`` True sets the place's turn to the block yaws read from the two height maps
    (:mod:`tvf.planning.yaw`; default: the method's); ``centre_picks`` True moves the GCTN's picks to the
    centres of the block faces under them (:mod:`tvf.models.pick_centre`; default: the method's);
    ``foresight`` "rigid" draws the search's images by moving the picked block on the height map instead
    of the VF, "rigid-falls" also tips a block off where it would not rest (:mod:`tvf.planning.rigid`;
    default: the VF; the simulator ones need an episode's environment: ``tvf eval``). Errors name the
    bad argument or file in one line."""
    if method not in LEARNED_METHODS:
        raise TvfError(f"unknown planner {method!r}; choose one of {', '.join(LEARNED_METHODS)}")
    unknown = sorted(set(planner) - set(PLANNER_OPTIONS))
    if unknown:
        raise TvfError(f"unknown planner option {unknown[0]!r}; choose one of {', '.join(PLANNER_OPTIONS)}")
    spec = PolicySpec(
        method,
        gctn=gctn,
        vf=vf,
        device=device,
        turns=turns,
        goal_mask=goal_mask,
        mask_places=mask_places,
        refine_yaw=refine_yaw,
        centred_share=centred_share,
        centre_picks=centre_picks,
        foresight=foresight,
        **planner,
    )
    policy = make_policy(spec)
    if hasattr(policy, "keep_images"):
        policy.keep_images = keep_images
    return Planner(method, policy)


def _color(image: np.ndarray, name: str) -> np.ndarray:
    image = np.asarray(image)
    shape = (*WORKSPACE.shape, 3)
    if image.shape != shape or image.dtype != np.uint8:
        raise TvfError(f"{name} must be a uint8 array of shape {shape} (the top-down colour image of "
                       f"docs/observation.md), not {image.dtype} {image.shape}")  # fmt: skip
    return image


def _height(image: np.ndarray, name: str) -> np.ndarray:
    image = np.asarray(image)
    if image.shape != WORKSPACE.shape or not np.issubdtype(image.dtype, np.floating):
        raise TvfError(f"{name} must be a float array of shape {WORKSPACE.shape} in metres above the "
                       f"table, not {image.dtype} {image.shape}")  # fmt: skip
    if not np.isfinite(image).all():
        raise TvfError(f"{name} holds NaN or infinite values; fill the holes (e.g. with 0, the table)")
    if image.max() > 1.0:
        raise TvfError(f"{name} reaches {image.max():.3g}: heights are metres above the table, not mm")
    return image.astype(np.float32)


def _pair(pixel: np.ndarray) -> tuple[int, int]:
    return int(pixel[0]), int(pixel[1])
