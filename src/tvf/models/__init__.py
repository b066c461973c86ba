"""Networks of tvf: GCTN (pick attention + goal-conditioned transport), visual foresight, checkpoints.

See docs/models.md. Submodules are imported explicitly (``from tvf.models.gctn import GCTN``).
"""
