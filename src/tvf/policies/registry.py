"""The method registry: each method's name, label, the models it loads, its planner settings, its factory.

Every command, the report and the experiment read this table; adding a method is one entry here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace

import torch

from tvf.device import pick_device
from tvf.errors import TvfError
from tvf.models.checkpoint import load_trained
from tvf.models.goal_mask import CENTRED_SHARE, CENTRING_RULES, PLACE_RULES, goal_masked
from tvf.models.pick_centre import centring_picks
from tvf.models.symmetry import check_turns, symmetrized
from tvf.planning.rigid import RIGID_FORESIGHTS, rigid_foresight
from tvf.planning.search import PlannerConfig, TreeSearch, widest_node
from tvf.planning.simulated import FORESIGHTS, SIMULATED
from tvf.policies.base import Policy
from tvf.policies.learned import GctnPolicy, OraclePolicy, SimulatedTvfPolicy, TvfPolicy

PLANNER_OPTIONS = (
    "k", "depth", "proposals", "pick_branches", "turns_depth", "alpha", "nms_radius", "tie_band", "root_k",
    "order_branch", "gamma", "root_alpha", "first_step_band", "snap_heights", "support_check",
    "place_search", "turn_search",
)  # fmt: skip
"""The PolicySpec fields that override a TVF method's planner preset (PlannerConfig fields of the same
name; their flags are ``--k``, ``--pick-branches``, ...)."""


def planner_flags() -> str:
    """The planner options as command-line flags, for error messages."""
    return ", ".join("--" + name.replace("_", "-") for name in PLANNER_OPTIONS)


@dataclass(frozen=True)
class PolicySpec:
    """What to run: a method, its checkpoints (None: the shipped weights), planner overrides, a device."""

    method: str
    gctn: str | None = None
    vf: str | None = None
    k: int | None = None
    depth: int | None = None
    device: str = "auto"
    proposals: str | None = None
    """Proposal rule override (kmeans | nms; docs/planner.md)."""
    pick_branches: int | None = None
    """Distinct picks a node branches over (1 = the argmax pick only)."""
    turns: int | None = None
    """Quarter turns of the scene the GCTN's maps are averaged over (1, 2, 4, or 8
    with their mirror images; docs/planner.md)."""
    turns_depth: int | None = None
    """TVF: the search levels, from the root, that use the symmetrised GCTN (the rest: the plain one)."""
    alpha: float | None = None
    """TVF: place pixels at least ALPHA times the best are candidates."""
    nms_radius: float | None = None
    """TVF: pixels between NMS proposals and between branched picks."""
    tie_band: float | None = None
    """TVF: root actions scoring within this of the best are ties, decided by the GCTN's order."""
    root_k: int | None = None
    """TVF: proposals of the real state (None: K, as every node)."""
    goal_mask: bool | None = None
    """Mask the GCTN's maps by the height difference to the goal (:mod:`tvf.models.goal_mask`; None: the
    method's, ``Method.goal_mask``; False: the paper's)."""
    mask_places: str | None = None
    """With the goal mask: the places it keeps (:data:`tvf.models.goal_mask.PLACE_RULES`; None: the
    method's, ``Method.mask_places``)."""
    refine_yaw: bool | None = None
    """Set the place's turn to the block yaws read from the current and the goal height maps where both
    readings are clear (:mod:`tvf.planning.yaw`; None: the method's, ``Method.refine_yaw``; False: the
    paper's)."""

    order_branch: bool | None = None
    """TVF with the goal mask: one proposal per node is the best place of the mask's ordered rule."""
    gamma: float | None = None
    """TVF: the discount per level of the search's score (None: the method's, the paper's 0.99)."""
    root_alpha: float | None = None
    """TVF: ``alpha`` for the root's proposals only (None: the method's, ``alpha`` everywhere)."""
    centred_share: float | None = None
    """With the goal mask's ``centred`` or ``ordered`` places: the share of the best-filled footprint a
    place's footprint must hold (None: the method's, ``Method.centred_share``)."""
    centre_picks: bool | None = None
    """Move each pick the GCTN chooses to the centre of the block face under it, read from the height map
    (:mod:`tvf.models.pick_centre`; None: the method's, ``Method.centre_picks``; False: the paper's)."""
    foresight: str | None = None
    """TVF: what scores the search's nodes, ``vf`` (the VF's imagined images; None: this), ``simulator``
    (each proposal executed in the episode's simulator and undone: a perfect foresight, an upper bound
    for research; :mod:`tvf.planning.simulated`), ``simulator-first`` (the first actions executed, the
    levels below imagined by the VF) or ``rigid`` (the picked block moved as a rigid body, no network:
    :mod:`tvf.planning.rigid`)."""
    first_step_band: float | None = None
    """TVF: only root actions whose one-step score is within this of the best one's compete by their
    subtrees (None: the method's, every root action for every method, the paper's)."""
    snap_heights: bool | None = None
    """TVF: set every height the VF moved to the nearest level a surface rests at before a node is scored
    and expanded (:mod:`tvf.planning.levels`; None: the method's; False: the paper's)."""
    support_check: bool | None = None
    """TVF: rank a node whose path places a block that would not rest on its parent's height map under
    every node that rests (:mod:`tvf.planning.support`; None: the method's; False: the paper's)."""
    place_search: int | None = None
    """TVF: pixels the executed place may move, along each axis, to where its one-step imagined image is
    nearest the goal (:meth:`tvf.planning.search.TreeSearch.polish`; None: the method's; 0: the paper's)."""
    turn_search: int | None = None
    """TVF: rotation bins either way the executed turn may change, chosen likewise (None: the method's;
    0: the paper's)."""

    def planner_overrides(self) -> dict:
        """The planner fields this spec sets (None: the method's preset)."""
        fields = {name: getattr(self, name) for name in PLANNER_OPTIONS}
        return {name: value for name, value in fields.items() if value is not None}


@dataclass(frozen=True)
class Method:
    """One entry of the registry."""

    name: str
    label: str
    """How reports and figures name it (the paper's names)."""
    build: Callable[[PolicySpec, object, torch.device], Policy]
    """``build(spec, env, device)``: the policy (``env`` is used only when ``needs_env``)."""
    models: tuple[str, ...] = ()
    """Model kinds it loads (their checkpoints come from the spec or the shipped weights)."""
    planner: PlannerConfig | None = None
    """The tree-search preset of a TVF method."""
    needs_env: bool = False
    """It reads the simulator (the oracle); learned methods act from images alone."""
    turns: int = 1
    """Test-time symmetrisation of its GCTN (:mod:`tvf.models.symmetry`; 1 = none, the paper)."""
    goal_mask: bool = False
    """Its GCTN's maps masked by the height difference to the goal (:mod:`tvf.models.goal_mask`)."""
    mask_places: str = "gap"
    """The places its goal mask keeps (:data:`tvf.models.goal_mask.PLACE_RULES`)."""
    centred_share: float = CENTRED_SHARE
    """Its goal mask's centring (``centred`` and ``ordered`` places;
    :func:`tvf.models.goal_mask.centred_places`)."""
    refine_yaw: bool = False
    """Its place turns corrected to the block yaws read from the height maps (:mod:`tvf.planning.yaw`)."""
    centre_picks: bool = False
    """Its GCTN's picks moved to the centres of the block faces under them (:mod:`tvf.models.pick_centre`)."""
    paper: str | None = None
    """The paper's method it runs, whose published numbers reports put beside it (None: none)."""


def _oracle(spec: PolicySpec, env, device: torch.device) -> Policy:
    if env is None:
        raise TvfError(
            "the oracle reads the simulator: build it with an environment (make_policy(spec, env))"
        )
    return OraclePolicy(env)


def load_gctn(spec: PolicySpec):
    """The spec's GCTN, goal-masked or not, its picks centred or not, and symmetrised over its turns (the
    method's unless the spec sets them)."""
    gctn = load_trained(spec.gctn, "gctn")
    gctn = goal_masked(gctn, goal_mask_of(spec), mask_places_of(spec), centred_share_of(spec))
    return symmetrized(centring_picks(gctn, centre_picks_of(spec)), turns_of(spec))


def turns_of(spec: PolicySpec) -> int:
    """The quarter turns ``spec``'s GCTN is averaged over: the spec's choice, else its method's default."""
    return spec.turns if spec.turns is not None else get_method(spec.method).turns


def goal_mask_of(spec: PolicySpec) -> bool:
    """Whether ``spec``'s GCTN is goal-masked: the spec's choice, else its method's default."""
    return spec.goal_mask if spec.goal_mask is not None else get_method(spec.method).goal_mask


def mask_places_of(spec: PolicySpec) -> str:
    """The place rule of ``spec``'s goal mask: the spec's choice, else its method's default."""
    return spec.mask_places if spec.mask_places is not None else get_method(spec.method).mask_places


def centred_share_of(spec: PolicySpec) -> float:
    """The centring of ``spec``'s goal mask: the spec's choice, else its method's default."""
    return spec.centred_share if spec.centred_share is not None else get_method(spec.method).centred_share


def refine_yaw_of(spec: PolicySpec) -> bool:
    """Whether ``spec``'s place turns are refined from the height maps: the spec's choice, else its
    method's default."""
    return spec.refine_yaw if spec.refine_yaw is not None else get_method(spec.method).refine_yaw


def centre_picks_of(spec: PolicySpec) -> bool:
    """Whether ``spec``'s picks move to their blocks' face centres: the spec's choice, else its method's."""
    return spec.centre_picks if spec.centre_picks is not None else get_method(spec.method).centre_picks


def foresight_of(spec: PolicySpec) -> str:
    """What scores ``spec``'s search: ``vf`` unless the spec asks for the ``simulator`` (or
    ``simulator-first``, ``rigid``)."""
    return spec.foresight or "vf"


def needs_env(spec: PolicySpec) -> bool:
    """Whether ``spec``'s policy reads the simulator it acts in (the oracle, a simulated foresight)."""
    return get_method(spec.method).needs_env or foresight_of(spec) in SIMULATED


def resolved_settings(spec: PolicySpec) -> dict:
    """Every setting ``spec`` acts with, its method's defaults filled in where the spec leaves them (None):
    the GCTN's turns and image rules, and a TVF method's whole planner (less ``batched``, which changes
    the cost, not the actions). Two specs with the same models and the same settings act alike, so an
    evaluation records these to refuse a resume under a method whose defaults changed since."""
    method = get_method(spec.method)
    settings: dict = {}
    if "gctn" in method.models:
        settings.update(
            turns=turns_of(spec), goal_mask=goal_mask_of(spec), mask_places=mask_places_of(spec),
            centred_share=centred_share_of(spec), refine_yaw=refine_yaw_of(spec),
            centre_picks=centre_picks_of(spec),
        )  # fmt: skip
    if method.planner is not None:
        settings.update({k: v for k, v in asdict(planner_of(spec)).items() if k != "batched"})
        settings["foresight"] = foresight_of(spec)
    return settings


def _gctn(spec: PolicySpec, env, device: torch.device) -> Policy:
    return GctnPolicy(load_gctn(spec), device, refine_yaw_of(spec))


def _tvf(spec: PolicySpec, env, device: torch.device) -> Policy:
    if foresight_of(spec) in SIMULATED:
        return _simulated_tvf(spec, env, device)
    foresight = foresight_of(spec)
    vf = rigid_foresight(foresight) if foresight in RIGID_FORESIGHTS else load_trained(spec.vf, "vf")
    return TvfPolicy(load_gctn(spec), vf, planner_of(spec), device, spec.method, refine_yaw_of(spec))


def _simulated_tvf(spec: PolicySpec, env, device: torch.device) -> Policy:
    foresight = foresight_of(spec)
    if env is None:
        raise TvfError(
            f"--foresight {foresight} executes the search's actions in the simulator of the episode, so "
            "only tvf eval and tvf ablate run it (in Python: make_policy(spec, env))"
        )
    executed = SIMULATED[foresight]
    vf = load_trained(spec.vf, "vf").eval().to(device) if executed is not None else None
    proposer = TreeSearch(load_gctn(spec).eval().to(device), vf, planner_of(spec))
    return SimulatedTvfPolicy(env, proposer, spec.method, refine_yaw_of(spec), executed)


IMAGE_RULES = {"goal_mask": True, "refine_yaw": True, "mask_places": "cells", "centre_picks": True}
"""What every learned method reads from the two height maps besides its networks, each chosen on
validation seeds (docs/results.md): the GCTN's maps masked by the height difference to the goal ("A
goal-difference mask"), its places kept to the lowest layer still to fill, filled from its ends and
corners in, each block beside a finished one on its own cell ("Cells, not fitting centres"), and its
picks moved to the centres of the block faces ("Layered places, second round"), the
place turns corrected to the block yaws read from the maps ("Turns read from the height maps"). The
paper's: --goal-mask False --refine-yaw False --centre-picks False (docs/deviations.md P12-P14, P18)."""

PAPER_SMALL = PlannerConfig(k=2, depth=1)
"""The paper's TVF-Small: K = 2 proposals, one imagined step (tvf-facts §7)."""
PAPER_LARGE = PlannerConfig(k=3, depth=3)
"""The paper's TVF-Large: K = 3 proposals (k-means over the place map's top pixels), three steps."""

NO_IMAGE_RULES = "-no-image-rules"
"""The suffix of the methods that run one of ours with none of :data:`IMAGE_RULES` (the Method defaults,
the paper's: nothing read from the height maps) and everything else of ours: its turns and its search."""


def _without_image_rules(method: Method) -> Method:
    """``method`` reading nothing from the height maps besides its networks (every :data:`IMAGE_RULES` set
    to the paper's), its GCTN's turns and its search kept: the row that shows what the search buys where
    the image rules do not already finish every episode (docs/results.md, "The search without the image
    rules")."""
    paper = {f.name: f.default for f in fields(Method) if f.name in IMAGE_RULES}
    return replace(
        method, name=method.name + NO_IMAGE_RULES, label=f"{method.label}, no image rules", **paper
    )


_OURS: tuple[Method, ...] = (
    # every method averages the GCTN over the 4 quarter turns of the scene (TVF: for the root's
    # proposals only; TVF-L also over their mirror images, turns 8), chosen on validation seeds
    # (docs/results.md); the paper's is --turns 1
    Method("gctn", "GCTN", _gctn, models=("gctn",), turns=4, **IMAGE_RULES, paper="gctn"),
    # TVF-S keeps the GCTN's greedy action unless the foresight shows another clearly better (a tie
    # band of 0.002, about a seventh of a misplaced block; docs/results.md, "TVF-S's tie band"); the
    # paper's rule is --tie-band 0
    Method(
        "tvf-small",
        "TVF-S",
        _tvf,
        ("gctn", "vf"),
        PlannerConfig(k=2, depth=1, turns_depth=1, tie_band=0.002),
        turns=4,
        **IMAGE_RULES,
        paper="tvf-small",
    ),
    # TVF-L: distinct proposals (NMS, three picks), chosen on validation seeds (docs/results.md); its
    # first actions from a lower threshold (three distinct root proposals in 96.7 % of decisions;
    # docs/results.md, "Distinct first actions"); the paper's rule is --proposals kmeans
    # --pick-branches 1 --turns 1 --root-alpha 0.01 with IMAGE_RULES' paper flags
    Method(
        "tvf-large",
        "TVF-L",
        _tvf,
        ("gctn", "vf"),
        PlannerConfig(3, 3, proposals="nms", pick_branches=3, turns_depth=1, root_alpha=0.001),
        turns=8,
        **IMAGE_RULES,
        paper="tvf-large",
    ),
)

METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method("oracle", "oracle", _oracle, needs_env=True),
        *_OURS,
        # the same three with the paper's planner rules and nothing read from the height maps (every
        # Method default is the paper's), so the rows can be compared with the paper's
        Method("gctn-paper", "GCTN, paper rules", _gctn, models=("gctn",), paper="gctn"),
        Method("tvf-small-paper", "TVF-S, paper rules", _tvf, ("gctn", "vf"), PAPER_SMALL, paper="tvf-small"),
        Method("tvf-large-paper", "TVF-L, paper rules", _tvf, ("gctn", "vf"), PAPER_LARGE, paper="tvf-large"),
        # ours with nothing read from the height maps: their turns and their search only
        *(_without_image_rules(m) for m in _OURS),
    )
}
PLANNER_METHODS = tuple(name for name, m in METHODS.items() if m.planner is not None)
LEARNED_METHODS = tuple(name for name, m in METHODS.items() if not m.needs_env)
"""The methods that act from images alone (every one but the oracle)."""
_CACHE: dict[PolicySpec, Policy] = {}


def get_method(name: str) -> Method:
    """The registry entry of ``name``; an unknown name is a one-line error listing the methods."""
    if name not in METHODS:
        hint = ""
        if VARIANT_SEP in name:
            base, foresight = split_variant(name)
            hint = (
                f" (METHOD{VARIANT_SEP}FORESIGHT names are for tvf experiment --methods; here: "
                f"--method {base} --foresight {foresight})"
            )
        raise TvfError(f"unknown method {name!r}; choose one of {', '.join(METHODS)}{hint}")
    return METHODS[name]


VARIANT_SEP = "+"
"""Joins a search method and a foresight in an experiment's method list, ``tvf-large-paper+rigid``: the
method with its search scored by that foresight instead of the VF (``--foresight``), evaluated into its
own folder beside the method's, so one experiment or sweep holds both rows."""


def split_variant(name: str) -> tuple[str, str | None]:
    """``"tvf-large-paper+rigid"`` -> ``("tvf-large-paper", "rigid")``; a plain name -> ``(name, None)``."""
    base, sep, foresight = name.partition(VARIANT_SEP)
    return base, (foresight if sep else None)


def check_variant(name: str) -> None:
    """A method name or a ``METHOD+FORESIGHT`` variant that can run, else a one-line error naming the fix."""
    base, foresight = split_variant(name)
    get_method(base)
    if foresight is None:
        return
    if base not in PLANNER_METHODS:
        raise TvfError(f"{base} does not search, so it takes no foresight ({name}); a foresight variant "
                       f"needs one of {', '.join(PLANNER_METHODS)}")  # fmt: skip
    others = [f for f in FORESIGHTS if f != "vf"]
    if foresight not in others:
        own = f" (the VF is the method's own: write {base})" if foresight == "vf" else ""
        raise TvfError(f"unknown foresight {foresight!r} in {name}; choose one of {', '.join(others)}{own}")


def paper_method(name: str) -> str | None:
    """The paper's method that ``name`` (or a foresight variant of it) runs, for its published numbers;
    None for others and unknowns."""
    base, _ = split_variant(name)
    return METHODS[base].paper if base in METHODS else None


def label(name: str) -> str:
    """The method's display name, a foresight variant's with its foresight (unknown names are shown as
    they are)."""
    base, foresight = split_variant(name)
    if base not in METHODS:
        return name
    return METHODS[base].label + (f", {foresight} foresight" if foresight else "")


def variant_order(name: str) -> tuple[int, int] | None:
    """Where ``name`` goes in tables: its method's place in the registry, then the foresight's (the VF's
    own first); None for names the registry does not know."""
    base, foresight = split_variant(name)
    if base not in METHODS or (foresight is not None and foresight not in FORESIGHTS):
        return None
    return list(METHODS).index(base), FORESIGHTS.index(foresight or "vf")


def planner_of(spec: PolicySpec) -> PlannerConfig:
    """The planner of a TVF spec: the method's preset with the spec's overrides (K, depth, proposals)."""
    method = get_method(spec.method)
    if method.planner is None:
        raise TvfError(f"{spec.method} does not plan; planner methods are {', '.join(PLANNER_METHODS)}")
    changes = spec.planner_overrides()
    if "k" in changes and "pick_branches" not in changes:  # a smaller K shares fewer picks
        widest = widest_node(changes["k"], changes.get("root_k", method.planner.root_k))
        changes["pick_branches"] = max(1, min(method.planner.pick_branches, widest))
    if "alpha" in changes and "root_alpha" not in changes:  # an alpha of one's own holds at the root too
        changes["root_alpha"] = None
    try:
        return replace(method.planner, **changes)
    except ValueError as exc:
        raise TvfError(f"{exc.args[0]}; fix the planner flags ({planner_flags()})") from None


def make_policy(spec: PolicySpec, env=None) -> Policy:
    """A new policy for ``spec`` (models are loaded here; errors name the bad flag or file)."""
    method = check_spec(spec)
    return method.build(spec, env, pick_device(spec.device))


def check_spec(spec: PolicySpec) -> Method:
    """``spec``'s method, after checking that its flags fit it (one-line errors naming the flag); no model
    is read."""
    method = get_method(spec.method)
    overrides = spec.planner_overrides()
    if method.planner is None and overrides:
        names = ", ".join("--" + name.replace("_", "-") for name in overrides)
        raise TvfError(f"{spec.method} does not search; planner options need one of "
                       f"{', '.join(PLANNER_METHODS)} (drop {names})")  # fmt: skip
    if spec.foresight is not None:
        _check_foresight(spec, method)
    if method.planner is not None:
        planner = planner_of(spec)  # a bad K or depth fails before any model is read
        if planner.order_branch and not goal_mask_of(spec):
            raise TvfError("--order-branch proposes the goal mask's ordered places, which this "
                           f"{spec.method} does not use; add --goal-mask True")  # fmt: skip
    if spec.turns is not None:
        if "gctn" not in method.models:
            raise TvfError(
                f"{spec.method} has no GCTN to symmetrise; --turns needs gctn, tvf-small or tvf-large"
            )
        check_turns(spec.turns)
    if spec.goal_mask and "gctn" not in method.models:
        raise TvfError(f"{spec.method} has no GCTN to mask; --goal-mask needs gctn, tvf-small or tvf-large")
    if spec.refine_yaw and "gctn" not in method.models:
        raise TvfError(f"{spec.method} does not turn blocks by rotation bins; --refine-yaw needs gctn, "
                       "tvf-small or tvf-large")  # fmt: skip
    if spec.centre_picks and "gctn" not in method.models:
        raise TvfError(f"{spec.method} has no GCTN picks to centre; --centre-picks needs gctn, tvf-small or "
                       "tvf-large")  # fmt: skip
    if spec.mask_places is not None:
        if spec.mask_places not in PLACE_RULES:
            rules = ", ".join(PLACE_RULES)
            raise TvfError(f"unknown --mask-places {spec.mask_places!r}; choose one of {rules}")
        if not goal_mask_of(spec):
            raise TvfError(f"--mask-places narrows the goal mask, which {spec.method} does not use here; "
                           "add --goal-mask True")  # fmt: skip
    if spec.centred_share is not None:
        _check_centred_share(spec)
    return method


def _check_foresight(spec: PolicySpec, method: Method) -> None:
    """A ``--foresight`` that exists and has a search to score, else a one-line error."""
    if spec.foresight not in FORESIGHTS:
        raise TvfError(f"unknown --foresight {spec.foresight!r}; choose one of {', '.join(FORESIGHTS)}")
    if method.planner is None:
        searches = ", ".join(PLANNER_METHODS)
        raise TvfError(f"{spec.method} does not search; --foresight needs one of {searches}")
    if spec.foresight in RIGID_FORESIGHTS and spec.vf is not None:
        raise TvfError(f"--foresight {spec.foresight} draws the images without a network, so --vf {spec.vf} "
                       "would be ignored; drop --vf, or use --foresight vf")  # fmt: skip
    if spec.foresight in SIMULATED and (spec.place_search or spec.turn_search):
        raise TvfError(f"--place-search and --turn-search polish the action on an imagined image, which "
                       f"--foresight {spec.foresight} does not draw for it; drop them, or use --foresight "
                       "vf or rigid")  # fmt: skip


def _check_centred_share(spec: PolicySpec) -> None:
    """A ``--centred-share`` that is a fraction and has centred places to act on, else a one-line error."""
    if not 0 < spec.centred_share <= 1:
        raise TvfError(f"--centred-share must be a fraction in (0, 1], got {spec.centred_share}")
    if not goal_mask_of(spec) or mask_places_of(spec) not in CENTRING_RULES:
        raise TvfError("--centred-share sets how the goal mask centres its places; add --goal-mask True "
                       "--mask-places ordered (or centred, layered, cells)")  # fmt: skip


def check_policy(spec: PolicySpec) -> None:
    """Fail fast, before any worker or cell starts, on a bad method, flag or checkpoint: the policy is
    built (its models read) unless it needs its episode's simulator, whose flags alone are checked."""
    if needs_env(spec):
        check_spec(spec)
    else:
        make_policy(spec)


def policy_for(spec: PolicySpec, env=None) -> Policy:
    """This process's policy for ``spec``: learned ones are loaded once per process and reused."""
    if needs_env(spec):
        return make_policy(spec, env)
    if spec not in _CACHE:
        _CACHE[spec] = make_policy(spec)
    return _CACHE[spec]


def forget_cached_policies() -> None:
    """Drop the per-process policy cache (after the shipped weights changed, in tests)."""
    _CACHE.clear()
