"""The real shipped weights (not smoke stand-ins): they load as recorded in provenance.json, and the GCTN
builds one fixed training-task scene.

The scene is an easy one on purpose (stack-tower, validation seed 3: the shipped GCTN solves seeds 3-19
of this task), so re-trained weights that ship later should pass too; a failure here means the shipped
files, their loading or the action pipeline broke, or the new weights are much weaker on training tasks.
"""

from __future__ import annotations

import torch

from tvf.evaluate.runner import policy_episode
from tvf.models.checkpoint import load_model
from tvf.policies import PolicySpec
from tvf.tasks import get_task
from tvf.weights import KINDS, provenance, shipped_checkpoint


def test_the_shipped_weights_load_as_their_provenance_records():
    record = provenance()["models"]
    for kind in KINDS:
        model, ckpt = load_model(shipped_checkpoint(kind), kind)
        assert ckpt.step == record[kind]["step"] and shipped_checkpoint(kind).name == record[kind]["file"]
        assert sum(p.numel() for p in model.parameters()) == record[kind]["parameters"]
        assert all(torch.isfinite(p).all() for p in model.parameters())


def test_the_shipped_gctn_builds_a_training_task_scene():
    result = policy_episode(get_task("stack-tower"), 3, PolicySpec("gctn"))
    assert result.success, result
    assert result.steps == 3 and result.primitives == ["ok"] * 3 and result.progress == 1.0


def test_the_shipped_gctn_has_quarter_turn_tied_kernels():
    """Shipped since session 27 (docs/results.md, "C4 kernels"): its pick map turns exactly with the scene."""
    model, _ = load_model(shipped_checkpoint("gctn"), "gctn")
    assert model.preset.gctn_kernels == "c4"
    generator = torch.Generator().manual_seed(0)
    current, goal = (torch.rand(1, 4, 160, 160, generator=generator) for _ in range(2))
    with torch.no_grad():
        pick = model.pick_logits(current, goal)
        turned = model.pick_logits(torch.rot90(current, 1, (-2, -1)), torch.rot90(goal, 1, (-2, -1)))
    assert torch.allclose(torch.rot90(pick, 1, (-2, -1)), turned, atol=1e-4 * float(pick.abs().max()))
