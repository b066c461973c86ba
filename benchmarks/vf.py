"""Visual-foresight costs on this CPU, and the model time of one TVF-Large decision.

For each preset: train-step time at batch 1 and 8, batched inference images/s at batch 1, 27 and 81
against 27 single calls, and a TVF-Large decision (K=3, depth 3: GCTN on 1, 3, 9 states and VF on 3, 9,
27 children, batched per depth, goal features computed once; top-K by the best rotation per pixel
stands in for k-means, whose cost is negligible).

Prints one JSON object. Usage: python benchmarks/vf.py [--paper] [--presets lite,smoke] [--repeats N]
[--threads 2] [--nchw] [--device cuda].
"""

from __future__ import annotations

import torch

from common import best_seconds, on, preset_benchmark_main
from tvf.models.backbone import count_conv_macs, count_parameters, set_channels_last
from tvf.models.gctn import GCTN
from tvf.models.presets import ModelPreset
from tvf.models.vf import ACTION_CHANNELS, VisualForesight


def random_actions(batch: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
    return {
        "rgbh": torch.randn(batch, 4, 160, 160, generator=generator),
        "pick": torch.randint(0, 160, (batch, 2), generator=generator),
        "place": torch.randint(0, 160, (batch, 2), generator=generator),
        "yaw": torch.rand(batch, generator=generator) * 6.283,
    }


def train_step_seconds(model: VisualForesight, batch: dict[str, torch.Tensor], repeats: int) -> float:
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)

    def step() -> None:
        optimizer.zero_grad(set_to_none=True)
        model.loss(batch["rgbh"], batch["pick"], batch["place"], batch["yaw"], batch["rgbh"]).backward()
        optimizer.step()

    return best_seconds(step, repeats)


def predict_seconds(model: VisualForesight, batch: dict[str, torch.Tensor], repeats: int) -> float:
    return best_seconds(
        lambda: model.predict_rgbh(batch["rgbh"], batch["pick"], batch["place"], batch["yaw"]), repeats
    )


def top_k_places(place_logits: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The k best place pixels (by their best rotation) per state: pixels (B, k, 2), yaws (B, k)."""
    b, r, h, w = place_logits.shape
    best, best_bin = place_logits.max(dim=1)
    index = best.reshape(b, -1).topk(k, dim=1).indices
    pixels = torch.stack([index // w, index % w], dim=-1)
    bins = best_bin.reshape(b, -1).gather(1, index)
    return pixels, bins.float() * (6.283185307179586 / r)


def decision_seconds(gctn: GCTN, vf: VisualForesight, repeats: int, k: int = 3, depth: int = 3,
                     device: torch.device | None = None) -> float:  # fmt: skip
    """Model time of one TVF-Large decision (the tree's GCTN and VF calls, batched per depth)."""
    generator = torch.Generator().manual_seed(1)
    root = torch.randn(1, 4, 160, 160, generator=generator).to(device)
    goal = torch.randn(1, 4, 160, 160, generator=generator).to(device)

    @torch.no_grad()
    def decide() -> None:
        goal_features = gctn.transport.goal_features(goal)
        states = root
        for _ in range(depth):
            n = states.shape[0]
            pick_logits = gctn.pick_logits(states, goal)
            flat = pick_logits.reshape(n, -1).argmax(dim=1)
            picks = torch.stack([flat // 160, flat % 160], dim=1)
            place_logits = gctn.place_map(states, None, picks, goal_features=goal_features)
            places, yaws = top_k_places(place_logits, k)
            states = vf.predict_rgbh(
                states.repeat_interleave(k, dim=0),
                picks.repeat_interleave(k, dim=0),
                places.reshape(-1, 2),
                yaws.reshape(-1),
            )

    return best_seconds(decide, repeats)


def bench_preset(preset: ModelPreset, repeats: int, channels_last: bool, device: torch.device
                 ) -> dict[str, object]:  # fmt: skip
    generator = torch.Generator().manual_seed(0)
    torch.manual_seed(0)
    model = set_channels_last(VisualForesight(preset), channels_last)
    side = preset.image_size + 2 * preset.vf_pad
    out: dict[str, object] = {
        "preset": preset.as_dict(),
        "params": count_parameters(model),
        "gmac": count_conv_macs(model.fcn, (1, ACTION_CHANNELS, side, side)) / 1e9,
    }
    model.to(device)
    for batch_size in (1, 8):
        seconds = train_step_seconds(model, on(random_actions(batch_size, generator), device), repeats)
        out[f"train_step_s_b{batch_size}"] = seconds
        out[f"train_samples_per_s_b{batch_size}"] = batch_size / seconds
    for batch_size in (1, 27, 81):
        seconds = predict_seconds(model, on(random_actions(batch_size, generator), device), repeats)
        out[f"predict_s_b{batch_size}"] = seconds
        out[f"predict_images_per_s_b{batch_size}"] = batch_size / seconds
    singles = [on(random_actions(1, generator), device) for _ in range(27)]
    seconds = best_seconds(
        lambda: [model.predict_rgbh(s["rgbh"], s["pick"], s["place"], s["yaw"]) for s in singles], repeats
    )
    out["predict_s_27_single_calls"] = seconds
    out["predict_images_per_s_27_single_calls"] = 27 / seconds
    gctn = set_channels_last(GCTN(preset), channels_last).to(device)
    out["tvf_large_decision_s"] = decision_seconds(gctn, model, repeats, device=device)
    return out


def main() -> None:
    preset_benchmark_main("vf", bench_preset, __doc__)


if __name__ == "__main__":
    main()
