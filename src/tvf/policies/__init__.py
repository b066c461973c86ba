"""Policies: the contract (:class:`Policy`), the built-in methods and the method registry."""

from tvf.policies.base import BatchPolicy, Observation, Policy, act_all
from tvf.policies.learned import GctnPolicy, OraclePolicy, SimulatedTvfPolicy, TvfPolicy
from tvf.policies.registry import (
    LEARNED_METHODS,
    METHODS,
    PLANNER_METHODS,
    Method,
    PolicySpec,
    centre_picks_of,
    centred_share_of,
    check_policy,
    check_spec,
    check_variant,
    foresight_of,
    forget_cached_policies,
    get_method,
    goal_mask_of,
    label,
    make_policy,
    mask_places_of,
    needs_env,
    paper_method,
    planner_of,
    policy_for,
    refine_yaw_of,
    resolved_settings,
    split_variant,
    turns_of,
    variant_order,
)

__all__ = [
    "LEARNED_METHODS", "METHODS", "PLANNER_METHODS", "BatchPolicy", "GctnPolicy", "Method", "Observation",
    "OraclePolicy", "Policy", "PolicySpec", "SimulatedTvfPolicy", "TvfPolicy", "act_all", "centre_picks_of",
    "centred_share_of", "check_policy", "check_spec", "check_variant", "foresight_of",
    "forget_cached_policies", "get_method", "goal_mask_of", "label", "make_policy", "mask_places_of",
    "needs_env", "paper_method", "planner_of", "policy_for", "refine_yaw_of", "resolved_settings",
    "split_variant", "turns_of", "variant_order",
]  # fmt: skip
