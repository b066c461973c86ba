"""Benchmark of the observation pipeline: time per observation and fidelity per camera resolution.

Each scene (``build_fidelity_scene``: table, flat tiles, stacks of 1-3 cubes) is imaged by
``orthographic_heightmap`` as the max over 4 x 4 samples per pixel (``supersample=4``: the cell
max that fusion estimates; errors without a suffix are against it) and centre-sampled
(``..._vs_center``). Then, per resolution, the three cameras are rendered and fused with and
without hole filling. ``gross_frac``: pixels more than 5 mm off; ``color_mae``: mean absolute
colour difference (0-255) over all pixels and channels.

Prints one JSON object. Run pinned to one core for the timings, e.g.
``taskset -c 0 .venv/bin/python benchmarks/camera.py``. Takes about 30 s.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from functools import partial

import numpy as np
import pybullet as p
import pybullet_data

from tvf.geometry import WORKSPACE
from tvf.sim import camera as cam

RESOLUTIONS = ((640, 480), (512, 384), (480, 360), (448, 336), (400, 300), (320, 240), (240, 180))


def _timed(fn, repeats: int):
    """Median wall time of ``repeats`` calls and the last result."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def _errors(color: np.ndarray, height: np.ndarray, ref_color: np.ndarray, ref_height: np.ndarray) -> dict:
    err = np.abs(height.astype(np.float64) - ref_height)
    return {
        "mae_mm": 1000 * float(err.mean()),
        "gross_frac": float((err > 0.005).mean()),  # pixels more than 5 mm off
        "color_mae": float(np.abs(color.astype(np.float64) - ref_color).mean()),
    }


def _render_all(client: int, cameras) -> list:
    return [cam.render_rgbd(client, c) for c in cameras]


def measure_scene(client: int, seed: int, resolutions, repeats: int, plane: bool) -> list[dict]:
    p.resetSimulation(physicsClientId=client)
    if plane:  # a textured ground plane under the table: heavier, closer to a full scene
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        p.loadURDF("plane.urdf", (0, 0, -0.001), physicsClientId=client)
    cam.build_fidelity_scene(client, seed)
    ref_color, ref_height = cam.orthographic_heightmap(client, WORKSPACE, supersample=4)
    _, center_height = cam.orthographic_heightmap(client, WORKSPACE, with_color=False)
    rows = []
    for width, height in resolutions:
        cameras = cam.reference_cameras(width, height)
        t_render, views = _timed(partial(_render_all, client, cameras), repeats)
        t_fuse, fused = _timed(partial(cam.fuse_with_coverage, views, cameras), repeats)
        t_fill, filled = _timed(partial(cam.fill_holes, *fused), repeats)
        holes = ~fused[2]
        row = {
            "seed": seed,
            "width": width,
            "height": height,
            "render_s": t_render,
            "fuse_s": t_fuse,
            "fill_s": t_fill,
            "empty_frac": float(holes.mean()),
            # how well filling guesses the holes (0 if there are none)
            "hole_mae_mm": 1000 * float(np.abs(filled[1] - ref_height)[holes].sum() / max(holes.sum(), 1)),
            "mae_mm_filled_vs_center": 1000 * float(np.abs(filled[1] - center_height).mean()),
        }
        for name, (color, hmap) in (("raw", fused[:2]), ("filled", filled)):
            for key, val in _errors(color, hmap, ref_color, ref_height).items():
                row[f"{key}_{name}"] = val
        rows.append(row)
    return rows


def summarize(rows: list[dict]) -> list[dict]:
    """Mean over seeds per resolution, plus seconds per observation (3 renders + fusion)."""
    out = []
    for width, height in sorted({(r["width"], r["height"]) for r in rows}, reverse=True):
        sel = [r for r in rows if (r["width"], r["height"]) == (width, height)]
        keys = [k for k in sel[0] if k not in ("seed", "width", "height")]
        mean = {k: float(np.mean([r[k] for r in sel])) for k in keys}
        mean["obs_s_raw"] = mean["render_s"] + mean["fuse_s"]
        mean["obs_s_filled"] = mean["obs_s_raw"] + mean["fill_s"]
        out.append({"width": width, "height": height, **{k: round(v, 5) for k, v in mean.items()}})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--plane", action="store_true", help="add pybullet_data's textured plane (timing)")
    parser.add_argument("--per-scene", action="store_true", help="also print every scene's rows")
    args = parser.parse_args()
    client = p.connect(p.DIRECT)
    try:
        rows = [
            r for s in args.seeds for r in measure_scene(client, s, RESOLUTIONS, args.repeats, args.plane)
        ]
    finally:
        p.disconnect(client)
    result = {
        "machine": platform.processor() or platform.machine(),
        "seeds": args.seeds,
        "repeats": args.repeats,
        "plane": args.plane,
        "default": {
            "width": cam.ObservationConfig().width,
            "height": cam.ObservationConfig().height,
            "fill_holes": cam.ObservationConfig().fill_holes,
        },
        "summary": summarize(rows),
    }
    if args.per_scene:
        result["scenes"] = rows
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
