"""The top-k table of distinct morphologies (no Ray)."""

from __future__ import annotations

import csv
import json

import pytest

from smorphi_rl.training.topk import (
    CSV_FIELDS,
    EPISODE_BEST_KEY,
    EpisodeBest,
    TopMorphologies,
    encode_bests,
    episode_bests,
    write_tables,
)


def _bests(rows):
    return [EpisodeBest.from_row(r) for r in rows]


def test_distinct_shapes_ranked_by_r1_and_first_sighting_kept():
    top = TopMorphologies()
    top.add_episode_bests(
        "ppo", _bests([["m", 1, 2, 3, 90.0, 50, 85.0], ["m", 4, 5, 6, 95.0, 60, 89.0]]), env_steps=1000
    )
    top.add_episode_bests(
        "ppo", _bests([["m", 1, 2, 3, 90.0, 50, 85.0], ["m", 7, 8, 9, 96.0, 60, 90.0]]), env_steps=2000
    )
    top.add_episode_bests(
        "ppo", _bests([["m", 1, 2, 4, 90.0, 50, 85.0]]), env_steps=3000
    )  # same metrics: same morphology
    ranked = top.top(5)
    assert [f.theta for f in ranked] == [(7.0, 8.0, 9.0), (4.0, 5.0, 6.0), (1.0, 2.0, 3.0)]
    assert ranked[2].env_steps == 1000 and ranked[2].variants == 2  # first seen kept; two triples reached it
    assert len(top.top(2)) == 2


def test_maps_are_kept_apart():
    top = TopMorphologies()
    top.add_episode_bests("ppo", _bests([["a", 1, 2, 3, 90.0, 50, 85.0], ["b", 1, 2, 3, 80.0, 50, 75.0]]), env_steps=10)
    assert top.maps() == ["a", "b"] and len(top) == 2
    assert [f.R1 for f in top.top(5, "b")] == [75.0]


def test_tables_round_trip(tmp_path):
    top = TopMorphologies()
    top.add_episode_bests("impala", _bests([["m", 95, 59, 103, 98.5, 99, 88.6]]), env_steps=3000)
    write_tables(top.top(3), tmp_path / "t.csv", tmp_path / "t.md")
    rows = list(csv.DictReader((tmp_path / "t.csv").open()))
    assert tuple(rows[0]) == CSV_FIELDS and rows[0]["theta1"] == "95" and rows[0]["P_len"] == "99"
    md = (tmp_path / "t.md").read_text()
    assert "| 1 | IMPALA | m | (95, 59, 103) | 98.50 | 99 | 88.60 | 3,000 | 1 |" in md


def test_a_row_with_a_field_missing_or_extra_is_refused_by_line(tmp_path):
    """csv fills a short row's missing fields with None: `compare` crashed on `None.upper()`."""
    from smorphi_rl.errors import SmorphiError
    from smorphi_rl.training.topk import read_csv

    top = TopMorphologies()
    top.add_episode_bests("ppo", _bests([["m", 95, 59, 103, 98.5, 99, 88.6]]), env_steps=3000)
    write_tables(top.top(3), tmp_path / "t.csv", tmp_path / "t.md")
    whole = (tmp_path / "t.csv").read_text()
    header, row = whole.splitlines()
    for bad in (row.rsplit(",", 1)[0], row + ",1"):
        (tmp_path / "t.csv").write_text(f"{header}\n{bad}\n")
        with pytest.raises(SmorphiError, match="line 2: not a row smorphi-rl writes"):
            read_csv(tmp_path / "t.csv")


def test_a_table_larger_than_any_run_writes_is_refused_before_it_is_read(tmp_path, monkeypatch):
    """A 55 MB crafted morphologies.csv took `compare --runs` to 1 GB: its size is checked first."""
    from smorphi_rl.errors import SmorphiError
    from smorphi_rl.training import topk

    top = TopMorphologies()
    top.add_episode_bests("ppo", _bests([["m", 95, 59, 103, 98.5, 99, 88.6]]), env_steps=3000)
    write_tables(top.top(3), tmp_path / "t.csv", tmp_path / "t.md")
    assert len(topk.read_csv(tmp_path / "t.csv")) == 1
    monkeypatch.setattr(topk, "MAX_CSV_BYTES", (tmp_path / "t.csv").stat().st_size - 1)
    with pytest.raises(SmorphiError, match="more than a table smorphi-rl writes"):
        topk.read_csv(tmp_path / "t.csv")


def test_episode_bests_round_trip_and_drop_what_is_not_one():
    best = EpisodeBest("map-1", (135.0, 56.0, 125.0), 97.1, 66, 90.5)
    encoded = encode_bests([best.to_row(), float("nan"), ["too", "short"]])
    assert episode_bests({EPISODE_BEST_KEY: encoded}) == [best]
    assert json.loads(encoded) == [["map-1", 135.0, 56.0, 125.0, 97.1, 66, 90.5]]
    assert episode_bests({}) == []
