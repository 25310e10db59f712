"""Every JSON file and line is strict JSON: a figure with no value is null, never NaN."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl import jsontext
from smorphi_rl.protocol import NO_OPTIMUM
from smorphi_rl.training.run import RunSummary


def strict(text: str) -> object:
    """What a strict reader (jq, JavaScript's JSON.parse) makes of `text`: NaN and Infinity are refused."""

    def refuse(name: str) -> None:
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_a_value_that_is_not_a_number_is_written_null_at_any_depth() -> None:
    value = {"a": math.nan, "b": [1.5, -math.inf, (np.float32("nan"), 2)], "c": {"d": np.float64(math.inf)}, "e": 3}
    assert strict(jsontext.dumps(value)) == {"a": None, "b": [1.5, None, [None, 2]], "c": {"d": None}, "e": 3}


def test_what_cannot_be_strict_json_is_refused_rather_than_written() -> None:
    with pytest.raises(ValueError, match="Out of range float values are not JSON compliant"):
        jsontext.dumps([np.float32(1.0)], default=lambda v: math.nan)


def test_a_run_summary_on_a_map_with_no_optimum_is_strict_json() -> None:
    summary = RunSummary(Path("r"), "ppo", 2000, 1, 1.0, False, None, {"big": NO_OPTIMUM}, None, {},
                         evaluation={"median_gap": math.nan, "share_within_1pct": math.nan, "starts": 20})  # fmt: skip
    assert "NaN" in json.dumps(summary.to_dict())  # what Python's json would have written
    read = strict(summary.to_json())
    assert isinstance(read, dict)
    assert read["exact_optimum"]["big"]["R1"] is None and read["evaluation"]["median_gap"] is None
    assert read["evaluation"]["starts"] == 20
