"""Strict JSON for every file and line smorphi-rl writes: a figure that is not a number (NaN, an infinity) is written
null, so `jq`, JavaScript and every other strict reader parse it (Python's `json` writes `NaN`, which they refuse)."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def finite(value: Any) -> Any:
    """`value` with every non-finite float, at any depth of its dicts, lists and tuples, replaced by None."""
    if isinstance(value, float | np.floating):  # numpy's too: `default=float` turns them into floats afterwards
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def dumps(value: Any, **kwargs: Any) -> str:
    """`json.dumps` of `finite(value)`, refusing (ValueError) anything that would still not be strict JSON."""
    return json.dumps(finite(value), allow_nan=False, **kwargs)
