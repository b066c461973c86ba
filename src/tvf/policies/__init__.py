"""Policies: the contract (:class:`Policy`), the built-in methods and the method registry."""

from tvf.policies.base import Observation, Policy
from tvf.policies.learned import GctnPolicy, OraclePolicy, TvfPolicy
from tvf.policies.registry import (
    METHODS,
    PLANNER_METHODS,
    Method,
    PolicySpec,
    forget_cached_policies,
    get_method,
    label,
    make_policy,
    planner_of,
    policy_for,
)

__all__ = [
    "METHODS", "PLANNER_METHODS", "GctnPolicy", "Method", "Observation", "OraclePolicy", "Policy",
    "PolicySpec", "TvfPolicy", "forget_cached_policies", "get_method", "label", "make_policy",
    "planner_of", "policy_for",
]  # fmt: skip
