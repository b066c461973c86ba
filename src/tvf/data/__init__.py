"""Demonstration data: generation, the HDF5 episode format, datasets and augmented samplers.

Typical use::

    from tvf.data import open_dataset, demo_subset, GctnSampler, VfSampler

    ds = open_dataset("data/demos/train")
    subset = demo_subset(ds, n_demos=10, run_seed=0)
    episodes = ds.load_all(e for eps in subset.values() for e in eps)
    batch = GctnSampler(episodes, batch_size=8, seed=0).sample()

See docs/data.md for the file format and the sample dictionaries.
"""

from tvf.data.augment import Se2, sample_se2, transform_pixels, transform_points, warp
from tvf.data.dataset import DemoDataset, demo_subset, open_dataset, write_manifest
from tvf.data.format import (
    FORMAT_VERSION,
    DataError,
    Episode,
    EpisodeInfo,
    read_episode,
    read_frames,
    read_info,
    seal,
    subpixel_to_pixel,
    world_to_subpixel,
    write_episode,
)
from tvf.data.generation import GenerationPlan, GenerationReport, collect_episode, generate, split_seeds
from tvf.data.samplers import IDENTITY_FRACTION, GctnSampler, VfSampler

__all__ = [
    "FORMAT_VERSION",
    "IDENTITY_FRACTION",
    "DataError",
    "DemoDataset",
    "Episode",
    "EpisodeInfo",
    "GctnSampler",
    "GenerationPlan",
    "GenerationReport",
    "Se2",
    "VfSampler",
    "collect_episode",
    "demo_subset",
    "generate",
    "open_dataset",
    "read_episode",
    "read_frames",
    "read_info",
    "sample_se2",
    "seal",
    "split_seeds",
    "subpixel_to_pixel",
    "transform_pixels",
    "transform_points",
    "warp",
    "world_to_subpixel",
    "write_episode",
    "write_manifest",
]
