"""Baselines and ground truth beside the env: random shapes, NSGA-II, the exhaustive design space."""
