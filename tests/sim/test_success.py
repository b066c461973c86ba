import math

import numpy as np

from tvf.sim.success import evaluate_structure, match_targets, pose_matches

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
