"""GCTN costs on this CPU: train-step time at batch 1, 2 and 8, greedy action time, planner place maps.

Prints one JSON object. Usage: python benchmarks/gctn.py [--paper] [--presets lite,smoke] [--repeats N]
[--threads 2] [--nchw] [--device cuda] (on a GPU: the paper preset's samples/s against the paper's
0.08 s a step). The ``paper`` preset runs only with --paper (minutes on a CPU). ``--presets lite,lite+c4``
puts the GCTN with quarter-turn-tied kernels (``--gctn-kernels c4``) beside the plain one; ``lite+c4+w0.25``
is that GCTN at width 0.25 (``--gctn-width 0.25``).
"""

from __future__ import annotations

import torch

from common import best_seconds, on, preset_benchmark_main
from tvf.models.backbone import count_conv_macs, count_parameters, set_channels_last
from tvf.models.gctn import GCTN
from tvf.models.presets import ModelPreset


def random_batch(batch: int, generator: torch.Generator, n_rotations: int) -> dict[str, torch.Tensor]:
    """Random normalised RGB-H states/goals and labels (costs do not depend on the content)."""
    return {
        "current": torch.randn(batch, 4, 160, 160, generator=generator),
        "goal": torch.randn(batch, 4, 160, 160, generator=generator),
        "pick": torch.randint(0, 160, (batch, 2), generator=generator),
        "place": torch.randint(0, 160, (batch, 2), generator=generator),
        "rot": torch.randint(0, n_rotations, (batch,), generator=generator),
    }


def gctn_size(model: GCTN, preset: ModelPreset) -> dict[str, float]:
    """Parameters and forward GMACs (convolutions only; the correlation is counted separately)."""
    side = preset.image_size if preset.pad_features else preset.image_size + preset.crop
    attention_macs = count_conv_macs(model.attention.fcn, (1, 8, preset.image_size, preset.image_size))
    transport_macs = 3 * count_conv_macs(model.transport.key, (1, 4, side, side))
    return {
        "params_attention": count_parameters(model.attention),
        "params_transport": count_parameters(model.transport),
        "gmac_attention": attention_macs / 1e9,
        "gmac_transport_fcns": transport_macs / 1e9,
    }


def train_step_seconds(model: GCTN, batch: dict[str, torch.Tensor], repeats: int) -> float:
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)

    def step() -> None:
        optimizer.zero_grad(set_to_none=True)
        loss = model.loss(batch["current"], batch["goal"], batch["pick"], batch["place"], batch["rot"])
        loss["total"].backward()
        optimizer.step()

    return best_seconds(step, repeats)


def bench_preset(preset: ModelPreset, repeats: int, channels_last: bool, device: torch.device
                 ) -> dict[str, object]:  # fmt: skip
    generator = torch.Generator().manual_seed(0)
    torch.manual_seed(0)
    model = set_channels_last(GCTN(preset), channels_last)
    out: dict[str, object] = {"preset": preset.as_dict(), **gctn_size(model, preset)}
    model.to(device)
    for batch_size in (1, 2, 8):
        batch = on(random_batch(batch_size, generator, preset.n_rotations), device)
        seconds = train_step_seconds(model, batch, repeats)
        out[f"train_step_s_b{batch_size}"] = seconds
        out[f"train_samples_per_s_b{batch_size}"] = batch_size / seconds
    one = on(random_batch(1, generator, preset.n_rotations), device)
    with torch.no_grad():
        out["act_s_b1"] = best_seconds(lambda: model.act(one["current"], one["goal"]), repeats)
        goal_features = model.transport.goal_features(one["goal"])
        for batch_size in (9, 27):
            many = on(random_batch(batch_size, generator, preset.n_rotations), device)
            out[f"place_map_s_b{batch_size}_shared_goal"] = best_seconds(
                lambda m=many: model.place_map(m["current"], None, m["pick"], goal_features=goal_features),
                repeats,
            )
    return out


def main() -> None:
    preset_benchmark_main("gctn", bench_preset, __doc__)


if __name__ == "__main__":
    main()
