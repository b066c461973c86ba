"""Samplers and the SE(2) augmentation: shapes, the reference's draw, and geometric consistency."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from data_factory import make_episode
from torch.utils.data import DataLoader

from tvf.data import GctnSampler, Se2, VfSampler, open_dataset, sample_se2, transform_pixels, warp
from tvf.data.augment import IMAGE_CENTER, inside, transform_points
from tvf.data.format import world_to_subpixel
from tvf.data.samplers import VfRolloutSampler, expert_reach
from tvf.geometry import bin_to_yaw, rotate_pixels, world_to_pixel, wrap_symmetric
from tvf.tasks import BLOCK_SYMMETRY


@pytest.fixture(scope="module")
def synthetic():
    eps = [make_episode("stack-stair", s, 5, rng_seed=s) for s in range(3)]
    return eps + [make_episode("stack-tower", 10, 4, rng_seed=10)]


def test_gctn_batch_shapes_and_types(synthetic):
    batch = GctnSampler(synthetic, batch_size=3).sample(rng=np.random.default_rng(0))
    for name in ("current", "goal"):
        assert (
            batch[f"{name}_color"].shape == (3, 160, 160, 3) and batch[f"{name}_color"].dtype == torch.float32
        )
        assert (
            batch[f"{name}_height"].shape == (3, 160, 160) and batch[f"{name}_height"].dtype == torch.float32
        )
    assert batch["pick"].shape == batch["place"].shape == (3, 2) and batch["pick"].dtype == torch.int64
    assert batch["rot_bin"].shape == (3,) and batch["rot_bin"].dtype == torch.int64
    assert ((batch["pick"] >= 0) & (batch["pick"] < 160)).all()
    assert batch["aug_yaw"].shape == (3,) and batch["aug_shift"].shape == (3, 2)


def test_vf_batch_shapes_and_types(synthetic):
    batch = VfSampler(synthetic, batch_size=2).sample(rng=np.random.default_rng(1))
    assert batch["next_color"].shape == (2, 160, 160, 3) and batch["next_height"].shape == (2, 160, 160)
    assert batch["yaw"].dtype == torch.float32 and batch["identity"].dtype == torch.bool


def test_rollout_samples_are_consecutive_stored_steps(synthetic):
    sampler = VfRolloutSampler(synthetic, augment=False, horizon=3)
    b = sampler.sample(6, np.random.default_rng(3))
    assert b["picks"].shape == b["places"].shape == (6, 3, 2) and b["yaws"].shape == (6, 3)
    assert not b["identity"].any()
    for k in range(6):
        ep, step = synthetic[int(b["episode"][k])], int(b["step"][k])
        assert step + 3 <= ep.n_steps  # every step of the rollout exists
        assert np.array_equal(b["current_height"][k].numpy(), ep.height[step])
        for j in range(3):
            assert np.array_equal(b[f"frame{j + 1}_color"][k].numpy(), ep.color[step + j + 1])
            assert b["picks"][k, j].tolist() == world_to_pixel(ep.pick[step + j, :2]).tolist()
            assert b["places"][k, j].tolist() == world_to_pixel(ep.place[step + j, :2]).tolist()
            assert b["yaws"][k, j] == pytest.approx(ep.relative_yaws()[step + j])
        # the one-step keys are the rollout's first step, as VfSampler builds it
        assert np.array_equal(b["next_height"][k].numpy(), ep.height[step + 1])
        assert b["pick"][k].tolist() == b["picks"][k, 0].tolist()
    with pytest.raises(ValueError, match="horizon"):
        VfRolloutSampler(synthetic, horizon=0)


def test_augmented_rollouts_move_every_frame_and_point_alike(synthetic):
    plain = VfRolloutSampler(synthetic, augment=False, horizon=2).sample(8, np.random.default_rng(4))
    moved = VfRolloutSampler(synthetic, augment=True, horizon=2).sample(8, np.random.default_rng(4))
    assert np.any(moved["aug_yaw"].numpy() != 0)
    for k in range(8):
        se2 = Se2(moved["aug_yaw"][k : k + 1].numpy().astype(np.float64),
                  moved["aug_shift"][k : k + 1].numpy().astype(np.float64))  # fmt: skip
        ep = synthetic[int(moved["episode"][k])]
        frames = torch.from_numpy(ep.height[int(moved["step"][k]) + 2][None, None])
        assert torch.equal(warp(frames, se2)[0, 0], moved["frame2_height"][k])
        assert (moved["places"][k] >= 0).all() and (moved["places"][k] < 160).all()
    assert plain["episode"].tolist() == moved["episode"].tolist()  # the same draw, transformed


def test_unaugmented_samples_are_the_stored_data(synthetic):
    sampler = GctnSampler(synthetic, augment=False)
    for _ in range(5):
        b = sampler.sample(4, np.random.default_rng(_))
        for k in range(4):
            ep, step = synthetic[int(b["episode"][k])], int(b["step"][k])
            assert not ep.random[step]  # GCTN samples skip the random actions
            assert np.array_equal(b["current_color"][k].numpy(), ep.color[step])
            assert np.array_equal(b["goal_height"][k].numpy(), ep.height[-1])  # the goal is the last frame
            assert b["pick"][k].tolist() == world_to_pixel(ep.pick[step, :2]).tolist()
            assert int(b["rot_bin"][k]) == ep.rotation_bins(36)[step]


def test_draw_follows_the_reference(synthetic):
    rng = np.random.default_rng(0)
    gctn = GctnSampler(synthetic)
    ep, step, goal = gctn.draw(20000, rng)
    tasks = np.array([synthetic[e].task for e in ep])
    assert abs(np.mean(tasks == "stack-tower") - 0.5) < 0.02  # tasks uniformly, not episodes
    assert not any(synthetic[e].random[s] for e, s in zip(ep, step, strict=True))
    assert (goal == [synthetic[e].n_steps for e in ep]).all()  # the last frame is every goal
    vf = VfSampler(synthetic)
    ep, step, identity = vf.draw(20000, rng)
    assert abs(identity.mean() - 1 / 8) < 0.01
    assert any(synthetic[e].random[s] for e, s in zip(ep, step, strict=True))  # VF uses random steps too
    assert len(gctn) == 3 * 3 + 3 and len(vf) == 3 * 5 + 4


def test_identity_samples(synthetic):
    sampler = VfSampler(synthetic, identity_fraction=1.0)
    b = sampler.sample(3, np.random.default_rng(2))
    assert b["identity"].all() and torch.equal(b["pick"], b["place"]) and (b["yaw"] == 0).all()
    assert torch.equal(b["current_color"], b["next_color"]) and torch.equal(
        b["current_height"], b["next_height"]
    )


def test_same_seed_same_batches_and_dataloader(synthetic):
    a = VfSampler(synthetic, batch_size=2, seed=5)
    b = VfSampler(synthetic, batch_size=2, seed=5)
    ba, bb = next(iter(a)), next(iter(b))
    assert all(torch.equal(ba[k], bb[k]) for k in ba)
    loader = DataLoader(a, batch_size=None)
    assert torch.equal(next(iter(loader))["pick"], ba["pick"])
    assert sampler_item_is_fixed(a)


def sampler_item_is_fixed(sampler) -> bool:
    one, two = sampler.item(3), sampler.item(3)
    return all(torch.equal(one[k], two[k]) for k in one) and float(one["aug_yaw"][0]) == 0.0


def test_lazy_episodes_sample_like_loaded_ones(tmp_path, synthetic):
    from tvf.data import read_episode, write_episode

    for i, ep in enumerate(synthetic):
        write_episode(tmp_path / f"{i}.h5", ep)
    loaded = [read_episode(tmp_path / f"{i}.h5") for i in range(4)]
    lazy = [read_episode(tmp_path / f"{i}.h5", lazy=True) for i in range(4)]
    a = GctnSampler(loaded, seed=3).sample(2, np.random.default_rng(0))
    b = GctnSampler(lazy, seed=3).sample(2, np.random.default_rng(0))
    assert all(torch.equal(a[k], b[k]) for k in a)


# ---------------------------------------------------------------------------------- the transform
def test_pure_rotation_moves_a_marked_pixel_like_rotate_pixels():
    rng = np.random.default_rng(0)
    for _ in range(25):
        p = rng.integers(30, 130, 2)
        image = torch.zeros(1, 1, 160, 160)
        image[0, 0, p[0] - 1 : p[0] + 2, p[1] - 1 : p[1] + 2] = 1.0  # a 3x3 mark around p
        yaw = rng.uniform(-math.pi, math.pi)
        out = warp(image, Se2(np.array([yaw]), np.zeros((1, 2))))
        expected = rotate_pixels(p.astype(float), yaw, IMAGE_CENTER)
        q = transform_pixels(p[None, None], Se2(np.array([yaw]), np.zeros((1, 2))))[0, 0]
        assert np.abs(q - expected).max() <= 0.5 + 1e-9
        assert out[0, 0, q[0], q[1]] == 1.0
        rows, cols = np.nonzero(out[0, 0].numpy())
        assert np.hypot(rows.mean() - expected[0], cols.mean() - expected[1]) < 0.75  # nearest sampling


def test_a_world_yaw_is_the_same_image_turn():
    """Turning the scene by yaw about the image centre moves world points as rotate_xy does."""
    from tvf.geometry import pixel_to_world, rotate_xy

    xy = np.array([[0.6, 0.1], [0.3, -0.2]])
    centre = pixel_to_world(IMAGE_CENTER)
    yaw = 0.7
    se2 = Se2(np.array([yaw]), np.zeros((1, 2)))
    moved = transform_points(world_to_subpixel(xy)[None], se2)[0]
    assert np.allclose(pixel_to_world(moved), rotate_xy(xy - centre, yaw) + centre)


def test_sampled_transforms_keep_key_points_inside():
    rng = np.random.default_rng(0)
    points = rng.uniform(5, 155, (200, 2, 2))
    se2 = sample_se2(points, rng, margin=20)
    assert inside(transform_points(points, se2)).all() or np.any(se2.yaw == 0)
    kept = se2.yaw != 0
    from tvf.data.augment import probe_points

    assert inside(transform_points(probe_points(points, 20), se2))[kept].all()
    assert 0.8 < np.std(se2.yaw[kept]) / math.radians(60) < 1.2 or kept.sum() < 100


# ------------------------------------------------------------------- augmentation on real episodes
def landing_errors(episodes, batch: dict, k: int) -> tuple[float, float]:
    """How far sample ``k``'s action carries its picked block from where the block came to rest (px),
    with the labelled turn and with the opposite one, in the sample's (augmented) image frame. Also
    checks that the pick lies on a block and that the turn reaches the block's final yaw."""
    ep, step = episodes[int(batch["episode"][k])], int(batch["step"][k])
    mirrored = bool(batch["aug_mirror"][k])
    se2 = Se2(batch["aug_yaw"][k : k + 1].numpy().astype(np.float64),
              batch["aug_shift"][k : k + 1].numpy().astype(np.float64), np.array([mirrored]))  # fmt: skip
    pick, place = batch["pick"][k].numpy(), batch["place"][k].numpy()
    assert batch["current_height"][k, pick[0], pick[1]] >= 0.03  # the moved pick lies on a block
    # the picked block (nearest to the pick) and where it came to rest after the step
    before, after = ep.blocks[step], ep.blocks[step + 1]
    block = int(np.argmin(np.linalg.norm(before[:, :2] - ep.pick[step, :2], axis=1)))
    centre = transform_points(world_to_subpixel(before[block, :2])[None, None], se2)[0, 0]
    landed = transform_points(world_to_subpixel(after[block, :2])[None, None], se2)[0, 0]
    delta = float(bin_to_yaw(batch["rot_bin"][k].item(), 36))
    # the block's yaw plus the turn reaches its final yaw, mod 90 degrees (a mirror reverses both yaws)
    sense = -1.0 if mirrored else 1.0
    assert abs(
        wrap_symmetric(sense * (before[block, 3] - after[block, 3]) + delta, BLOCK_SYMMETRY)
    ) < math.radians(10)
    # the tool turns the block by delta about the pick point (image turn == world yaw)
    turned = [place + rotate_pixels(centre - pick, d, np.zeros(2)) for d in (delta, -delta)]
    return float(np.linalg.norm(turned[0] - landed)), float(np.linalg.norm(turned[1] - landed))


def test_augmented_actions_still_pick_the_block_and_reach_its_pose(real_root):
    episodes = open_dataset(real_root / "train").load_all()
    rng = np.random.default_rng(7)
    batches = [s.sample(32, rng) for s in (GctnSampler(episodes), VfSampler(episodes, identity_fraction=0.0))]
    errors, wrong_turn_errors = zip(
        *(landing_errors(episodes, b, k) for b in batches for k in range(32)), strict=True
    )
    assert max(errors) < 2.0, max(errors)  # pixel rounding and where the block really settled
    assert max(wrong_turn_errors) > 2.0  # the check can tell a sign error apart


def test_mirrored_samples_still_pick_the_block_and_reach_its_pose(real_root):
    """A mirrored GCTN sample is a consistent scene: the reflected pick lies on the block, and the
    negated turn (not the recorded one) carries the reflected block to where it came to rest."""
    episodes = open_dataset(real_root / "train").load_all()
    batch = GctnSampler(episodes, mirror=1.0).sample(32, np.random.default_rng(11))
    assert batch["aug_mirror"].all()
    recorded = [
        int(episodes[int(e)].rotation_bins(36)[int(s)])
        for e, s in zip(batch["episode"], batch["step"], strict=True)
    ]
    assert batch["rot_bin"].tolist() == [-b % 36 for b in recorded]
    errors, unnegated_errors = zip(*(landing_errors(episodes, batch, k) for k in range(32)), strict=True)
    assert max(errors) < 2.0, max(errors)
    assert max(unnegated_errors) > 2.0  # an unnegated label would not carry the block to its rest


def test_a_mirror_reverses_columns_and_costs_no_draw_when_off(synthetic):
    images = torch.arange(2 * 4 * 160 * 160, dtype=torch.float32).reshape(2, 4, 160, 160)
    flip = Se2(np.zeros(2), np.zeros((2, 2)), np.array([True, False]))
    out = warp(images, flip)
    assert torch.equal(out[0], images[0].flip(-1)) and torch.equal(out[1], images[1])
    points = np.array([[[10.0, 3.0]], [[10.0, 3.0]]])
    assert np.allclose(transform_points(points, flip), [[[10.0, 156.0]], [[10.0, 3.0]]])
    assert transform_pixels(np.array([[[4, 0]]]), flip.subset(slice(0, 1))).tolist() == [[[4, 159]]]
    plain = GctnSampler(synthetic).sample(16, np.random.default_rng(3))
    off = GctnSampler(synthetic, mirror=0.0).sample(16, np.random.default_rng(3))
    assert all(torch.equal(plain[k], off[k]) for k in plain) and not off["aug_mirror"].any()
    half = GctnSampler(synthetic, mirror=0.5).sample(400, np.random.default_rng(4))
    assert 0.4 < float(half["aug_mirror"].float().mean()) < 0.6
    assert not GctnSampler(synthetic, mirror=1.0).item(0)["aug_mirror"].any()  # validation: never mirrored
    with pytest.raises(ValueError, match="between 0 and 1"):
        GctnSampler(synthetic, mirror=1.5)


def test_expert_reach_stops_before_a_random_step():
    episode = make_episode("stack-stair", 0, 6, rng_seed=0)  # steps 0 and 3 are random
    assert expert_reach(episode).tolist() == [3, 3, 3, 6, 6, 6]


def test_hindsight_goals_are_later_frames_the_expert_reaches(synthetic):
    reference = GctnSampler(synthetic).draw(4000, np.random.default_rng(1))
    sampler = GctnSampler(synthetic, hindsight=0.5)
    ep, step, goal = sampler.draw(4000, np.random.default_rng(1))
    assert np.array_equal(ep, reference[0]) and np.array_equal(step, reference[1])  # the same steps drawn
    last = np.array([synthetic[e].n_steps for e in ep])
    reach = np.array([expert_reach(synthetic[e])[s] for e, s in zip(ep, step, strict=True)])
    assert ((goal > step) & ((goal <= reach) | (goal == last))).all()  # never past a random step
    relabelled = goal != last
    assert 0.2 < relabelled.mean() < 0.5  # half are drawn again; some of those land on the last frame
    pairs = {(int(s), int(g)) for s, g in zip(step[relabelled], goal[relabelled], strict=True)}
    assert pairs == {(1, 2), (1, 3), (2, 3)}  # every partial structure before the random step 3
    sampler.augment = False
    batch = sampler.sample(64, np.random.default_rng(2))
    for k in range(64):
        e, f = int(batch["episode"][k]), int(batch["goal_frame"][k])
        assert np.array_equal(batch["goal_height"][k].numpy(), synthetic[e].height[f])
    fixed = sampler.item(0)  # validation samples keep the last frame
    assert int(fixed["goal_frame"][0]) == synthetic[int(fixed["episode"][0])].n_steps
    with pytest.raises(ValueError, match="between 0 and 1"):
        GctnSampler(synthetic, hindsight=-0.1)
