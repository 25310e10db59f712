"""smorphi-rl: find the best shape for the Smorphi reconfigurable floor-cleaning robot on a map.

The core (geometry -> maps -> coverage) imports numpy, and for map files Pillow, PyYAML and SciPy; the
compiled fast path loads numba lazily, on the first evaluation. Importing the package registers the
environment with gymnasium (`gymnasium.make(smorphi_rl.ENV_ID)`, and `gymnasium.make_vec` for many at once), which
loads it only when made.
"""

__version__ = "0.1.0"

ENV_ID = "smorphi_rl/Morphology-v0"
"""The morphology MDP's gymnasium id (`smorphi_rl.env.MorphologyEnv`)."""


def _register() -> None:
    """Register ENV_ID with gymnasium by its entry point (idempotent; the env module is imported when made)."""
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="smorphi_rl.env:MorphologyEnv",
                           vector_entry_point="smorphi_rl.vector_env:make_vector")  # fmt: skip


_register()
