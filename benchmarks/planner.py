"""TVF decision latency: the batched tree search against the same search one node at a time.

For each preset (and each device: CPU, and CUDA when present) one scene's first observation is planned
with TVF-Large (K=3, depth 3: GCTN on 1 + 3 + 9 states, VF on 3 + 9 + 27 children) and TVF-Small
(K=2, depth 1). The same models serve both modes in the same run. `lite` uses the shipped weights when
they exist (realistic proposal counts); other presets use seeded random weights.

``--rules`` also times TVF-Large under other proposal rules side by side (same models, same run),
e.g. ``--rules kmeans,nms+picks3`` (``nms+picksP`` = NMS proposals branching over P picks; a further
``+turnsT`` averages the GCTN over T quarter turns of the scene, ``--turns``, and ``+tdepthD`` does so at
the first D levels only, ``--turns-depth``; ``+rootR``, ``+kK`` and ``+depthD`` set ``--root-k``, ``--k`` and
``--depth``, e.g. ``nms+picks3+turns4+tdepth1+root6+k2`` for a wide root over a narrow tree; ``+mask``
adds ``--goal-mask``, ``+placesRULE`` the mask with ``--mask-places RULE``, ``+centre`` adds
``--centre-picks``, ``+alphaA`` sets ``--alpha``, e.g. ``+alpha0.001``, and ``+polishPxT`` sets
``--place-search P --turn-search T``, e.g. ``+polish4x2``; the shipped TVF-L:
``nms+picks3+turns8+tdepth1+mask+rootalpha0.001``, with the block-centred picks and layered places:
``...+placeslayered+centre``).

``--vfs PATH[,PATH]`` also times every ``--rules`` entry of the ``lite`` preset with each of these VFs (a run
folder, .pt or .safetensors) in place of the shipped one, in the same run (``tvf-large/RULE/vf:PATH``):
the side-by-side measurement a new VF is judged by; ``rigid`` there is the foresight without a network
(``--foresight rigid``, :mod:`tvf.planning.rigid`; ``rigid-falls`` with falls). ``--gctns PATH[,PATH]``
does the same for other GCTNs (``tvf-large/RULE/gctn:PATH``, with the shipped VF), e.g. a run trained
with ``--gctn-kernels c4``.

Prints one JSON object. Usage: python benchmarks/planner.py [--presets lite,smoke] [--paper]
[--repeats N] [--threads 2] [--task stack-pyramid] [--rules kmeans,nms+picks3] [--vfs runs/vf]
[--gctns runs/gctn]
"""

from __future__ import annotations

import argparse
import json

import torch

from common import best_seconds
from tvf.errors import TvfError
from tvf.models.gctn import GCTN
from tvf.models.goal_mask import goal_masked
from tvf.models.images import to_rgbh
from tvf.models.pick_centre import centring_picks
from tvf.models.presets import get_preset
from tvf.models.symmetry import symmetrized
from tvf.models.vf import VisualForesight
from tvf.planning.rigid import RIGID_FORESIGHTS, rigid_foresight
from tvf.planning.search import PlannerConfig, TreeSearch


def load_models(preset_name: str, device: torch.device):
    if preset_name == "lite":
        try:
            from tvf.models.checkpoint import load_trained

            return (
                load_trained(None, "gctn", device),
                load_trained(None, "vf", device),
                True,
            )
        except Exception:  # noqa: BLE001 - no shipped weights: fall back to random ones
            pass
    preset = get_preset(preset_name)
    gctn = GCTN(preset, seed=0).eval().to(device)
    vf = VisualForesight(preset, seed=1).eval().to(device)
    return gctn, vf, False


def first_observation(task: str, seed: int = 1):
    from tvf.sim.env import TvfEnv

    env = TvfEnv(task)
    obs, info = env.reset(seed=seed)
    goal = info["goal"]
    env.close()
    return to_rgbh(obs["color"], obs["height"]), to_rgbh(goal["color"], goal["height"])


def rule_config(rule: str) -> tuple[dict, int, str | None, bool]:
    """PlannerConfig fields, GCTN turns, goal mask place rule (None: no mask) and centred picks of a rule
    name: kmeans | nms | nms+picksP, each optionally +turnsT (the GCTN averaged over T quarter turns,
    tvf.models.symmetry), +tdepthD, +rootR, +kK, +depthD, +mask (tvf.models.goal_mask), +placesRULE,
    +centre (tvf.models.pick_centre), +alphaA (``--alpha``), +rootalphaA (``--root-alpha``), +polishPxT
    (``--place-search P --turn-search T``)."""
    name, *options = rule.split("+")
    fields: dict = {"proposals": name}
    turns, places, centre = 1, None, False
    for option in options:
        if option.startswith("picks"):
            fields["pick_branches"] = int(option[len("picks") :])
        elif option.startswith("turns"):
            turns = int(option[len("turns") :])
        elif option.startswith("tdepth"):
            fields["turns_depth"] = int(option[len("tdepth") :])
        elif option == "mask":
            places = places or "gap"
        elif option.startswith("places"):
            places = option[len("places") :]
        elif option == "centre":
            centre = True
        elif option.startswith("alpha"):
            fields["alpha"] = float(option[len("alpha") :])
        elif option.startswith("rootalpha"):
            fields["root_alpha"] = float(option[len("rootalpha") :])
        elif option.startswith("polish"):
            place, _, turn = option[len("polish") :].partition("x")
            fields["place_search"], fields["turn_search"] = int(place), int(turn or 0)
        elif option.startswith("root"):
            fields["root_k"] = int(option[len("root") :])
        elif option.startswith("depth"):
            fields["depth"] = int(option[len("depth") :])
        elif option.startswith("k"):
            fields["k"] = int(option[len("k") :])
        else:
            raise SystemExit(
                f"unknown rule option {option!r} in {rule!r}; use +picksP, +turnsT, +tdepthD, +rootR, +kK, "
                "+depthD, +mask, +placesRULE, +centre, +alphaA, +rootalphaA or +polishPxT"
            )
    return fields, turns, places, centre


def _foresight(path: str, device: torch.device):
    """A VF run folder or file of ``--vfs``, or ``rigid`` / ``rigid-falls``: the foresight without a
    network."""
    from tvf.models.checkpoint import load_trained

    return rigid_foresight(path) if path in RIGID_FORESIGHTS else load_trained(path, "vf", device)


def bench(preset_name: str, device: torch.device, images, repeats: int, rules: list[str],
          vfs: tuple[str, ...] = (), gctns: tuple[str, ...] = ()) -> dict:  # fmt: skip
    gctn, vf, shipped = load_models(preset_name, device)
    from tvf.models.checkpoint import load_trained

    # (row suffix, GCTN, VF): the shipped pair, then each other model beside the shipped one
    pairs = [("", gctn, vf)]
    if preset_name == "lite":
        pairs += [(f"/vf:{path}", gctn, _foresight(path, device)) for path in vfs]
        pairs += [(f"/gctn:{path}", load_trained(path, "gctn", device), vf) for path in gctns]
    current, goal = (x.to(device) for x in images)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    out: dict = {"weights": "shipped" if shipped else "random"}
    for name, k, depth in (("tvf-large", 3, 3), ("tvf-small", 2, 1)):
        row = {}
        for batched in (True, False):
            search = TreeSearch(gctn, vf, PlannerConfig(k=k, depth=depth, batched=batched))

            def decide(s=search) -> None:
                s.search(current, goal)
                sync()

            row["batched_s" if batched else "node_by_node_s"] = best_seconds(decide, repeats)
            row["counts" if batched else "counts_node_by_node"] = search.search(current, goal).counts
        row["speedup"] = row["node_by_node_s"] / row["batched_s"]
        out[name] = row
    for rule in rules:
        fields, turns, places, centre = rule_config(rule)
        for suffix, policy_gctn, foresight in pairs:
            masked = goal_masked(policy_gctn, places is not None, places or "gap")
            model = symmetrized(centring_picks(masked, centre), turns)
            search = TreeSearch(model, foresight, PlannerConfig(**{"k": 3, "depth": 3, **fields}))
            seconds = best_seconds(lambda s=search: s.search(current, goal), repeats)
            counts = search.search(current, goal).counts
            out[f"tvf-large/{rule}{suffix}"] = {"batched_s": seconds, "counts": counts}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--presets", default="lite,smoke")
    parser.add_argument("--paper", action="store_true", help="also time the (slow on CPU) paper preset")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--task", default="stack-pyramid")
    parser.add_argument("--rules", default="", help="proposal rules timed side by side (kmeans,nms+picks3)")
    parser.add_argument("--vfs", default="", help="other VFs timed with every rule of lite, side by side")
    parser.add_argument("--gctns", default="", help="other GCTNs timed with every rule of lite, side by side")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    images = first_observation(args.task)
    devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    names = args.presets.split(",") + (["paper"] if args.paper else [])
    rules = [r for r in args.rules.split(",") if r]
    vfs = tuple(v for v in args.vfs.split(",") if v)
    gctns = tuple(g for g in args.gctns.split(",") if g)
    try:
        results = {
            str(device): {n: bench(n, device, images, args.repeats, rules, vfs, gctns) for n in names}
            for device in devices
        }
    except TvfError as error:  # a --vfs / --gctns path that is missing or holds the other model
        parser.exit(2, f"error: {error}\n")
    print(json.dumps({"planner": results, "threads": args.threads, "task": args.task}, indent=1))


if __name__ == "__main__":
    main()
