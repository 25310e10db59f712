"""Everything that imports ray or torch: RLlib configuration, the RLModule, callbacks, Tune runs."""
