"""The method registry and the policy contract."""

from dataclasses import replace

import numpy as np
import pytest

from tvf.errors import TvfError
from tvf.models.goal_mask import CENTRED_SHARE, mask_of
from tvf.planning.search import PlannerConfig
from tvf.policies import (
    METHODS,
    PLANNER_METHODS,
    OraclePolicy,
    Policy,
    PolicySpec,
    centre_picks_of,
    check_variant,
    get_method,
    goal_mask_of,
    label,
    make_policy,
    paper_method,
    planner_of,
    policy_for,
    refine_yaw_of,
    split_variant,
    variant_order,
)
from tvf.sim.factory import sim_env
from tvf.tasks import get_task


def test_planner_presets_and_overrides():
    assert PLANNER_METHODS == (
        "tvf-small", "tvf-large", "tvf-small-paper", "tvf-large-paper", "tvf-small-no-image-rules",
        "tvf-large-no-image-rules",
    )  # fmt: skip
    small, large = planner_of(PolicySpec("tvf-small")), planner_of(PolicySpec("tvf-large"))
    assert (small.k, small.depth, large.k, large.depth) == (2, 1, 3, 3)
    assert (large.proposals, large.pick_branches) == ("nms", 3)  # chosen on validation seeds
    assert (small.proposals, small.pick_branches) == ("kmeans", 1)  # the paper's rule
    assert planner_of(PolicySpec("tvf-large", k=2)).pick_branches == 2  # a smaller K shares fewer picks
    assert large.root_alpha == 0.001 and small.root_alpha is None  # TVF-L's first actions: docs/results.md
    paper = planner_of(PolicySpec("tvf-large", proposals="kmeans", pick_branches=1, turns=1, root_alpha=0.01))
    assert replace(paper, turns_depth=None, root_alpha=None) == PlannerConfig(k=3, depth=3)  # the paper's
    assert paper.alpha_at(1) == paper.alpha_at(2) == 0.01
    own = planner_of(PolicySpec("tvf-large", alpha=0.5))  # an alpha of one's own holds at the root too
    assert own.alpha_at(1) == own.alpha_at(2) == 0.5
    assert large.turns_depth == 1 and small.turns_depth == 1
    assert small.tie_band == 0.002 and large.tie_band == 0.0  # TVF-S keeps near ties for the GCTN
    assert planner_of(PolicySpec("tvf-small", tie_band=0.0)).tie_band == 0.0  # the paper's rule
    assert [get_method(m).turns for m in ("gctn", "tvf-small", "tvf-large")] == [4, 4, 8]
    with pytest.raises(TvfError, match="unknown method 'tvf-huge'"):
        planner_of(PolicySpec("tvf-huge"))
    with pytest.raises(TvfError, match="does not plan"):
        planner_of(PolicySpec("gctn"))
    with pytest.raises(TvfError, match="k >= 1 .*--k, --depth"):
        make_policy(PolicySpec("tvf-large", k=0))
    nms = planner_of(PolicySpec("tvf-large", proposals="nms", pick_branches=2))
    assert (nms.proposals, nms.pick_branches, nms.k) == ("nms", 2, 3)
    with pytest.raises(TvfError, match="unknown proposal rule"):
        planner_of(PolicySpec("tvf-small", proposals="topk"))


def test_the_spec_turns_choose_the_symmetrised_gctn():
    from tvf.models.gctn import GCTN
    from tvf.models.symmetry import SymmetrizedGCTN

    paper = make_policy(PolicySpec("gctn", turns=1, goal_mask=False, centre_picks=False))
    default = make_policy(PolicySpec("gctn"))
    assert isinstance(default.model, SymmetrizedGCTN) and default.model.turns == 4
    assert type(paper.model) is GCTN
    assert make_policy(PolicySpec("tvf-small")).search.gctn.turns == 4  # every method's default now
    assert (
        type(make_policy(PolicySpec("tvf-small", turns=1, goal_mask=False, centre_picks=False)).search.gctn)
        is GCTN
    )
    assert make_policy(PolicySpec("tvf-large")).search.gctn.turns == 8  # and the mirror images
    assert make_policy(PolicySpec("tvf-large", turns=2)).search.gctn.turns == 2


def test_the_spec_goal_mask_wraps_the_gctn_inside_the_turns():
    from tvf.models.gctn import GCTN
    from tvf.models.goal_mask import GoalMaskedGCTN
    from tvf.models.pick_centre import CentredPickGCTN
    from tvf.models.symmetry import SymmetrizedGCTN

    def plain(**options) -> PolicySpec:  # picks where the GCTN puts them: the mask right under the turns
        return PolicySpec(centre_picks=False, **options)

    masked = make_policy(plain(method="tvf-large", goal_mask=True)).search.gctn
    assert isinstance(masked, SymmetrizedGCTN) and isinstance(masked.gctn, GoalMaskedGCTN)
    assert isinstance(make_policy(plain(method="gctn", goal_mask=True, turns=1)).model, GoalMaskedGCTN)
    assert isinstance(make_policy(plain(method="gctn")).model.gctn, GoalMaskedGCTN)  # the GCTN's default
    assert type(make_policy(plain(method="gctn", goal_mask=False)).model.gctn) is GCTN  # the paper's
    assert isinstance(make_policy(plain(method="tvf-small")).search.gctn.gctn, GoalMaskedGCTN)
    assert isinstance(make_policy(plain(method="tvf-large")).search.gctn.gctn, GoalMaskedGCTN)
    assert type(make_policy(plain(method="tvf-large", goal_mask=False)).search.gctn.gctn) is GCTN
    default = make_policy(PolicySpec("gctn")).model.gctn  # centred picks wrap the masked GCTN
    assert isinstance(default, CentredPickGCTN) and isinstance(default.gctn, GoalMaskedGCTN)
    with pytest.raises(TvfError, match="oracle has no GCTN to mask; --goal-mask needs gctn"):
        make_policy(PolicySpec("oracle", goal_mask=True))


def test_the_spec_refine_yaw_reaches_the_policy_and_needs_a_gctn():
    assert make_policy(PolicySpec("gctn", refine_yaw=True)).refine_yaw is True
    assert make_policy(PolicySpec("tvf-large", refine_yaw=True)).refine_yaw is True
    assert make_policy(PolicySpec("gctn")).refine_yaw is True  # the GCTN's and TVF-S's default
    assert make_policy(PolicySpec("tvf-small")).refine_yaw is True
    assert make_policy(PolicySpec("gctn", refine_yaw=False)).refine_yaw is False  # the paper's
    assert make_policy(PolicySpec("tvf-large")).refine_yaw is True  # with the mask (docs/results.md)
    assert make_policy(PolicySpec("tvf-large", refine_yaw=False)).refine_yaw is False
    with pytest.raises(TvfError, match="oracle does not turn blocks by rotation bins; --refine-yaw needs"):
        make_policy(PolicySpec("oracle", refine_yaw=True))


def test_the_spec_mask_places_choose_the_goal_masks_place_rule():
    ordered = mask_of(make_policy(PolicySpec("tvf-large", goal_mask=True, mask_places="ordered")).search.gctn)
    assert ordered.places == "ordered" and mask_of(make_policy(PolicySpec("gctn")).model).places == "cells"
    assert mask_of(make_policy(PolicySpec("gctn", mask_places="gap")).model).places == "gap"
    assert mask_of(make_policy(PolicySpec("gctn", mask_places="centred", turns=1)).model).places == "centred"
    with pytest.raises(TvfError, match="unknown --mask-places 'tallest'; choose one of gap, centred"):
        make_policy(PolicySpec("gctn", mask_places="tallest"))
    with pytest.raises(TvfError, match="tvf-large does not use here; add --goal-mask True"):
        make_policy(PolicySpec("tvf-large", goal_mask=False, mask_places="ordered"))


def test_the_spec_centred_share_and_root_alpha_reach_the_mask_and_the_search():
    policy = make_policy(PolicySpec("tvf-large", mask_places="ordered", centred_share=0.6, root_alpha=0.001))
    assert mask_of(policy.search.gctn).share == 0.6 and policy.search.config.root_alpha == 0.001
    assert mask_of(make_policy(PolicySpec("gctn", mask_places="ordered")).model).share == CENTRED_SHARE
    with pytest.raises(TvfError, match=r"--centred-share must be a fraction in \(0, 1\], got 1.2"):
        make_policy(PolicySpec("gctn", mask_places="centred", centred_share=1.2))
    with pytest.raises(TvfError, match="add --goal-mask True --mask-places ordered"):
        make_policy(PolicySpec("gctn", mask_places="gap", centred_share=0.75))  # gap: nothing to centre
    assert mask_of(make_policy(PolicySpec("gctn", centred_share=0.75)).model).share == 0.75  # cells
    with pytest.raises(TvfError, match=r"drop --root-alpha"):
        make_policy(PolicySpec("gctn", root_alpha=0.001))


def test_the_spec_centre_picks_wrap_the_gctn_under_its_symmetrisation_and_need_a_gctn():
    from tvf.models.pick_centre import CentredPickGCTN
    from tvf.models.symmetry import SymmetrizedGCTN

    def centring(gctn) -> bool:
        while hasattr(gctn, "gctn"):
            if isinstance(gctn, CentredPickGCTN):
                return True
            gctn = gctn.gctn
        return False

    assert centring(make_policy(PolicySpec("gctn")).model)  # the default
    assert centring(make_policy(PolicySpec("tvf-large")).search.gctn)
    assert not centring(make_policy(PolicySpec("gctn", centre_picks=False)).model)
    assert isinstance(make_policy(PolicySpec("tvf-small", centre_picks=True)).search.gctn, SymmetrizedGCTN)
    with pytest.raises(TvfError, match="oracle has no GCTN picks to centre; --centre-picks needs gctn"):
        make_policy(PolicySpec("oracle", centre_picks=True))


def test_the_order_branch_needs_the_goal_mask_and_reaches_the_search():
    policy = make_policy(PolicySpec("tvf-large", goal_mask=True, order_branch=True, gamma=0.999))
    assert policy.search.config.order_branch is True and policy.search.config.gamma == 0.999
    assert make_policy(PolicySpec("tvf-small")).search.config.order_branch is False  # the paper's
    with pytest.raises(TvfError, match="--order-branch proposes the goal mask's ordered places, which this "
                       "tvf-large does not use; add --goal-mask True"):  # fmt: skip
        make_policy(PolicySpec("tvf-large", goal_mask=False, order_branch=True))
    with pytest.raises(TvfError, match=r"gamma must be in \(0, 1\], got 2.0; fix the planner flags"):
        make_policy(PolicySpec("tvf-large", gamma=2.0))
    searchers = (
        "tvf-small, tvf-large, tvf-small-paper, tvf-large-paper, tvf-small-no-image-rules, "
        "tvf-large-no-image-rules"
    )
    with pytest.raises(TvfError, match=rf"gctn does not search; planner options need one of {searchers} "
                       r"\(drop --tie-band, --order-branch\)"):  # fmt: skip
        make_policy(PolicySpec("gctn", tie_band=0.001, order_branch=True))  # not silently ignored


def image_rules(spec: PolicySpec) -> tuple[bool, bool, bool]:
    """What ``spec`` reads from the height maps: goal mask, refined turns, centred picks."""
    return goal_mask_of(spec), refine_yaw_of(spec), centre_picks_of(spec)


def without_image_rules_flags(ours: str) -> PolicySpec:
    """``ours`` with every image rule switched off by its flag."""
    return PolicySpec(ours, goal_mask=False, refine_yaw=False, centre_picks=False)


@pytest.mark.parametrize("ours", ["gctn", "tvf-small", "tvf-large"])
def test_the_paper_rules_methods_are_ours_with_every_paper_flag(ours):
    paper = PolicySpec(f"{ours}-paper")
    flags = without_image_rules_flags(ours)
    assert image_rules(paper) == image_rules(flags) == (False, False, False) != image_rules(PolicySpec(ours))
    assert get_method(paper.method).turns == 1 < get_method(ours).turns
    assert get_method(paper.method).models == get_method(ours).models
    assert paper_method(paper.method) == paper_method(ours) == ours  # the same published number
    if ours != "gctn":  # the search exactly as the paper's: k-means proposals, no tie band, one threshold
        k, depth = (2, 1) if ours == "tvf-small" else (3, 3)
        assert planner_of(paper) == PlannerConfig(k=k, depth=depth)
        assert planner_of(PolicySpec(paper.method, k=2)).k == 2  # overrides still apply
    assert paper_method("oracle") is None and paper_method("my-method") is None


@pytest.mark.parametrize("ours", ["gctn", "tvf-small", "tvf-large"])
def test_the_no_image_rules_methods_are_ours_reading_nothing_from_the_height_maps(ours):
    bare = PolicySpec(f"{ours}-no-image-rules")
    flags = without_image_rules_flags(ours)
    assert image_rules(bare) == image_rules(flags) == (False, False, False) != image_rules(PolicySpec(ours))
    assert get_method(bare.method).mask_places == get_method(f"{ours}-paper").mask_places  # the paper's
    assert get_method(bare.method).turns == get_method(ours).turns > 1  # our turns kept
    assert paper_method(bare.method) == ours and get_method(bare.method).models == get_method(ours).models
    if ours != "gctn":  # our search kept, with every override
        assert planner_of(bare) == planner_of(PolicySpec(ours)) != planner_of(PolicySpec(f"{ours}-paper"))
        assert planner_of(PolicySpec(bare.method, k=2)).k == 2


def test_labels_and_unknown_methods():
    assert [label(m) for m in METHODS] == [
        "oracle", "GCTN", "TVF-S", "TVF-L", "GCTN, paper rules", "TVF-S, paper rules", "TVF-L, paper rules",
        "GCTN, no image rules", "TVF-S, no image rules", "TVF-L, no image rules",
    ]  # fmt: skip
    assert label("my-method") == "my-method"
    with pytest.raises(TvfError, match="choose one of oracle, gctn, tvf-small, tvf-large, gctn-paper, "):
        get_method("magic")


def test_foresight_variants_name_a_search_method_and_a_foresight():
    assert split_variant("tvf-large-paper+rigid") == ("tvf-large-paper", "rigid")
    assert split_variant("tvf-large") == ("tvf-large", None)
    assert label("tvf-large-paper+rigid") == "TVF-L, paper rules, rigid foresight"
    assert paper_method("tvf-small-paper+rigid-falls") == "tvf-small"  # the paper's number of its method
    for name in ("tvf-large+rigid", "tvf-small-no-image-rules+simulator", "gctn"):
        check_variant(name)
    # each method's variants follow it, the VF's own first, before the next method
    names = ["tvf-small-paper", "tvf-large+rigid", "tvf-large", "gctn", "tvf-large+rigid-falls"]
    assert sorted(names, key=variant_order) == [
        "gctn", "tvf-large", "tvf-large+rigid", "tvf-large+rigid-falls", "tvf-small-paper",
    ]  # fmt: skip
    assert variant_order("mine") is None and variant_order("tvf-large+magic") is None
    for name, message in (
        ("gctn-paper+rigid", "gctn-paper does not search, so it takes no foresight"),
        ("tvf-large+magic", "unknown foresight 'magic' in tvf-large\\+magic; choose one of simulator, "),
        ("tvf-large+vf", "the VF is the method's own: write tvf-large"),
        ("magic+rigid", "unknown method 'magic'"),
    ):
        with pytest.raises(TvfError, match=message):
            check_variant(name)
    with pytest.raises(TvfError, match="here: --method tvf-large --foresight rigid"):
        get_method("tvf-large+rigid")  # tvf eval takes the foresight as a flag


def test_learned_policies_act_from_images_alone():
    env = sim_env(get_task("stack-stair"))
    obs, info = env.reset(seed=1)
    for name in ("gctn", "tvf-small"):
        policy = policy_for(PolicySpec(name))
        assert isinstance(policy, Policy) and policy.name == name
        policy.reset()
        action = policy.act({k: v.copy() for k, v in obs.items()}, info["goal"])  # plain arrays in
        assert action.shape == (2, 4) and np.isfinite(action).all()
    assert policy_for(PolicySpec("gctn")) is policy_for(PolicySpec("gctn"))  # loaded once per process


def test_the_oracle_keeps_its_simulator_inside():
    env = sim_env(get_task("stack-stair"))
    obs, info = env.reset(seed=1)
    oracle = make_policy(PolicySpec("oracle"), env)
    assert isinstance(oracle, OraclePolicy) and isinstance(oracle, Policy)
    action = oracle.act(obs, info["goal"])
    env.reset(seed=1)
    np.testing.assert_array_equal(action, env.oracle_action())
    with pytest.raises(TvfError, match="reads the simulator"):
        make_policy(PolicySpec("oracle"))
