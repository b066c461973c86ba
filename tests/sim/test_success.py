import math

import numpy as np
import pytest

from tvf.sim.success import (
    MISS_KINDS,
    TOLERANCE,
    Tolerance,
    evaluate_structure,
    match_targets,
    miss_kind,
    pose_matches,
    target_misses,
)

TARGETS = np.array([[0.5, 0.0, 0.025], [0.5, 0.05, 0.025]])
YAWS = np.array([0.3, 0.3])


def test_exact_placement_succeeds_in_any_block_order():
    p = evaluate_structure(TARGETS[::-1], YAWS, TARGETS, YAWS)
    assert p.success and p.fraction == 1.0 and sorted(p.block_to_target) == [0, 1]


def test_two_blocks_cannot_share_one_target():
    blocks = np.array([TARGETS[0], TARGETS[0] + [0.003, 0, 0]])
    p = evaluate_structure(blocks, YAWS, TARGETS, YAWS)
    assert not p.success and p.matched == 1 and p.fraction == 0.5


def test_tolerances_xy_z_and_yaw_modulo_quarter_turn():
    one_t, one_y = TARGETS[:1], YAWS[:1]
    assert pose_matches(one_t + [0.009, 0, 0], one_y, one_t, one_y).all()
    assert not pose_matches(one_t + [0.011, 0, 0], one_y, one_t, one_y).any()
    assert not pose_matches(one_t + [0, 0, 0.006], one_y, one_t, one_y).any()
    assert pose_matches(one_t, one_y + math.pi / 2 + math.radians(14), one_t, one_y).all()
    assert not pose_matches(one_t, one_y + math.radians(16), one_t, one_y).any()


def test_matching_is_maximum_not_greedy():
    # block 0 fits both targets, block 1 only target 0: a greedy pass in block order would fail.
    ok = np.array([[True, True], [True, False]])
    assert sorted(match_targets(ok).tolist()) == [0, 1]


# -------------------------------------------------------------- every tolerance, both signs, at the boundary
TOL = TOLERANCE
EPS = 1e-4  # 0.1 mm and 0.006 degrees on either side of a boundary


def _one_block_matches(offset_xyz=(0.0, 0.0, 0.0), dyaw: float = 0.0, target_yaw: float = 0.3) -> bool:
    target = TARGETS[:1]
    block = target + np.asarray(offset_xyz)
    return bool(pose_matches(block, np.array([target_yaw + dyaw]), target, np.array([target_yaw]))[0, 0])


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_position_tolerance_boundaries_on_every_axis_and_sign(axis: int, sign: float):
    tol = TOL.z if axis == 2 else TOL.xy
    inside, outside = np.zeros(3), np.zeros(3)
    inside[axis], outside[axis] = sign * (tol - EPS / 10), sign * (tol + EPS / 10)
    assert _one_block_matches(inside)
    assert not _one_block_matches(outside)


@pytest.mark.parametrize("angle", [0.0, math.pi / 4, 2.0, -2.5])
def test_xy_tolerance_is_a_radius_in_any_direction(angle: float):
    direction = np.array([math.cos(angle), math.sin(angle), 0.0])
    assert _one_block_matches((TOL.xy - EPS / 10) * direction)
    assert not _one_block_matches((TOL.xy + EPS / 10) * direction)


@pytest.mark.parametrize("target_yaw", [0.3, 0.0, math.pi - 0.01, -math.pi + 0.01])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_yaw_tolerance_boundaries_both_signs_modulo_a_quarter_turn(target_yaw: float, sign: float):
    tol = TOL.yaw
    for quarter in (0, 1, -1, 2):  # the block looks the same after each quarter turn
        turn = quarter * math.pi / 2
        assert _one_block_matches(dyaw=turn + sign * (tol - EPS), target_yaw=target_yaw)
        assert not _one_block_matches(dyaw=turn + sign * (tol + EPS), target_yaw=target_yaw)
    for far in (math.radians(40), math.radians(45), math.radians(30)):  # never within 15 degrees of a face
        assert not _one_block_matches(dyaw=sign * far, target_yaw=target_yaw)


def test_a_block_turned_minus_forty_degrees_is_not_placed():
    """The issue's example: without the absolute value, -40 degrees counted as placed."""
    p = evaluate_structure(TARGETS, YAWS + math.radians(-40), TARGETS, YAWS)
    assert p.matched == 0 and not p.success


def test_tolerances_are_strict_and_come_from_the_tolerance_given():
    """Exactly representable numbers: an error equal to the tolerance is outside it, and a custom
    Tolerance reaches the matching (evaluate_structure passes it on)."""
    tol = Tolerance(xy=0.25, z=0.125, yaw=0.25)
    target, yaw0 = np.array([[0.5, 0.0, 0.0]]), np.array([0.0])
    for block, yaw in (([0.75, 0.0, 0.0], 0.0), ([0.5, 0.0, 0.125], 0.0), ([0.5, 0.0, 0.0], 0.25)):
        assert not pose_matches(np.array([block]), np.array([yaw]), target, yaw0, tol).any()
    assert pose_matches(np.array([[0.74, 0.0, 0.12]]), np.array([0.24]), target, yaw0, tol).all()
    off = TARGETS + [0.02, 0, 0]  # 2 cm off: placed under a 3 cm tolerance only
    assert not evaluate_structure(off, YAWS, TARGETS, YAWS).success
    assert evaluate_structure(off, YAWS, TARGETS, YAWS, Tolerance(xy=0.03)).success


def test_a_single_block_matches_and_an_unmatched_block_gets_minus_one():
    assert evaluate_structure(TARGETS[:1], YAWS[:1], TARGETS[:1], YAWS[:1]).block_to_target == (0,)
    far = TARGETS + [[0.1, 0, 0], [0, 0, 0]]
    p = evaluate_structure(far, YAWS, TARGETS, YAWS)
    assert p.block_to_target == (-1, 1) and p.matched == 1 and p.fraction == 0.5
    assert match_targets(np.zeros((2, 0), bool)).tolist() == [-1, -1]


CELLS = np.array([[0.40, 0.00, 0.025], [0.45, 0.00, 0.025], [0.40, 0.00, 0.065]])


def _misses(blocks: np.ndarray, yaws: np.ndarray) -> list[dict]:
    progress = evaluate_structure(blocks, yaws, CELLS, np.zeros(3))
    return target_misses(blocks, yaws, CELLS, np.zeros(3), progress.block_to_target)


def test_misses_name_each_unfilled_target_and_how_its_nearest_block_misses_it():
    blocks = np.array([[0.40, 0.00, 0.025], [0.4503, 0.002, 0.025], [0.415, 0.00, 0.065]])
    yaws = np.array([0.0, math.radians(25.0), 0.0])
    misses = _misses(blocks, yaws)
    assert [m["target"] for m in misses] == [1, 2] and [m["kind"] for m in misses] == ["turn", "offset"]
    assert misses[0]["yaw_deg"] == pytest.approx(25.0) and misses[0]["xy_mm"] == pytest.approx(2.0)
    assert misses[1]["xy_mm"] == pytest.approx(15.0) and misses[1]["z_mm"] == pytest.approx(0.0)


def test_a_block_on_the_wrong_level_or_far_away_and_a_finished_structure():
    level = np.array([[0.40, 0.00, 0.025], [0.45, 0.00, 0.065], [0.40, 0.00, 0.065]])  # one a layer up
    assert [(m["target"], m["kind"], m["z_mm"]) for m in _misses(level, np.zeros(3))] == [(1, "level", 40.0)]
    away = np.array([[0.40, 0.00, 0.025], [0.60, 0.20, 0.025], [0.40, 0.00, 0.065]])
    assert [m["kind"] for m in _misses(away, np.zeros(3))] == ["away"]
    assert _misses(CELLS.copy(), np.zeros(3)) == []
    # fewer blocks than targets: the target left without a block is away, with no errors
    missing = target_misses(CELLS[:2], np.zeros(2), CELLS, np.zeros(3), (0, 1))
    assert missing == [{"target": 2, "xy_mm": None, "z_mm": None, "yaw_deg": None, "kind": "away"}]


@pytest.mark.parametrize(
    ("xy", "dz", "kind"),
    [(0.005, 0.0, "turn"), (0.012, 0.003, "offset"), (0.02, -0.04, "level"), (0.025, 0.0, "away")],
)
def test_miss_kinds_follow_the_tolerances_and_half_a_cell(xy, dz, kind):
    assert miss_kind(xy, dz) == kind and kind in MISS_KINDS
