"""Everything that imports torch, RLlib or Tune: RLlib configuration, the RLModule, callbacks, Tune runs (Ray's
core alone is also used by `cluster.py` and `search/on_ray.py`)."""
