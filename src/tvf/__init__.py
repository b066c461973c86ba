"""tvf: Transporters with Visual Foresight for pick-and-place rearrangement.

``tvf.load_planner``, ``tvf.Planner`` and ``tvf.Decision`` (the Python API, :mod:`tvf.api`) are loaded on
first use (PEP 562), so ``import tvf`` and ``tvf --help`` stay light.
"""

__version__ = "0.1.0"
__all__ = ["Decision", "Planner", "__version__", "load_planner"]
_API = ("Decision", "Planner", "load_planner")


def __getattr__(name: str):
    if name in _API:
        from tvf import api  # the top layer, re-exported lazily (tests/test_layers.py allows this one)

        return getattr(api, name)
    raise AttributeError(f"module 'tvf' has no attribute {name!r}")
