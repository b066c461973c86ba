"""Shared scaffolding of the model benchmarks: best-of-N timing and the per-preset command line."""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import torch

from tvf.device import pick_device
from tvf.models.presets import ModelPreset, get_preset


def best_seconds(fn: Callable[[], object], repeats: int, warmup: int = 1) -> float:
    """The fastest of ``repeats`` timed calls of ``fn`` after ``warmup`` untimed ones.

    The minimum, not the median: on a shared CPU other jobs only ever add time.
    """
    for _ in range(warmup):
        fn()
        _synchronize()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        _synchronize()  # CUDA runs asynchronously: a call is done when the device is
        times.append(time.perf_counter() - start)
    return min(times)


def _synchronize() -> None:
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()


def on(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    """The batch's tensors on ``device`` (they are drawn on the CPU, from a CPU generator)."""
    return {k: v.to(device) for k, v in batch.items()}


def named_preset(name: str) -> ModelPreset:
    """A preset by name, with variants after ``+``: ``c4``, the GCTN's quarter-turn-tied kernels, and
    ``wW``, the GCTN's attention and transport FCNs at width W (``lite+c4+w0.25``: `--gctn-width 0.25`)."""
    base, *variants = name.split("+")
    preset = get_preset(base)
    for variant in variants:
        if variant == "c4":
            preset = preset.replace(gctn_kernels="c4")
        elif variant.startswith("w") and _is_number(variant[1:]):
            preset = preset.replace(attention_width=float(variant[1:]), transport_width=float(variant[1:]))
        else:
            raise SystemExit(f"unknown preset variant {variant!r} in {name!r}: the variants are +c4 and "
                             "+wW (the GCTN at width W)")  # fmt: skip
    return preset


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def preset_benchmark_main(
    label: str,
    bench_preset: Callable[[ModelPreset, int, bool, torch.device], dict[str, object]],
    doc: str | None,
) -> None:
    """Parse the common flags, run ``bench_preset(preset, repeats, channels_last, device)`` for each preset
    and print one JSON object."""
    parser = argparse.ArgumentParser(description=doc)
    parser.add_argument("--presets", default="lite,smoke",
                        help="comma-separated preset names; NAME+c4: with the GCTN's C4 kernels; "
                        "NAME+wW: the GCTN at width W (e.g. lite+c4+w0.25)")  # fmt: skip
    parser.add_argument("--paper", action="store_true", help="also run the (slow) paper preset")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per item (the best is kept)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--nchw", action="store_true", help="contiguous NCHW instead of channels-last")
    parser.add_argument("--device", default="cpu", help="cpu | cuda | auto (CUDA when present)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    device = pick_device(args.device)
    names = args.presets.split(",") + (["paper"] if args.paper else [])
    results = {name: bench_preset(named_preset(name), args.repeats, not args.nchw, device) for name in names}
    meta = {"threads": args.threads, "repeats": args.repeats, "channels_last": not args.nchw,
            "device": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"}  # fmt: skip
    print(json.dumps({label: results, **meta}, indent=1))
