"""Benchmarks write their own section of docs/benchmarks.md and leave every other section as it was."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import _benchdocs


@pytest.fixture
def docs(tmp_path, monkeypatch):
    path = tmp_path / "benchmarks.md"
    monkeypatch.setattr(_benchdocs, "DOCS", path)
    return path


def test_a_section_is_rewritten_in_place_and_the_others_kept(docs):
    _benchdocs.write_section("a", "## A\n\nfirst")
    _benchdocs.write_section("b", "## B\n\nsecond")
    before_b = docs.read_text().split("<!-- BEGIN b -->")[1]
    _benchdocs.write_section("a", "## A\n\nagain")
    text = docs.read_text()
    assert text.startswith("# Benchmarks") and "again" in text and "first" not in text
    assert text.split("<!-- BEGIN b -->")[1] == before_b
    assert text.count("<!-- BEGIN a -->") == 1 and "_Written by `" in text and "cores" in text


def test_a_section_whose_end_marker_is_lost_is_refused_and_the_file_kept(docs):
    """Its BEGIN without an END after it was appended to as a second section; an END before its BEGIN raised an
    IndexError. Either is named, the file kept, no temporary file left."""
    _benchdocs.write_section("a", "## A\n\nfirst")
    _benchdocs.write_section("b", "## B\n\nsecond")
    for damaged in (docs.read_text().replace("<!-- END a -->", ""),
                    "<!-- END a -->\n" + docs.read_text().replace("<!-- END a -->", "")):  # fmt: skip
        docs.write_text(damaged)
        with pytest.raises(SystemExit, match="BEGIN a -->' has no '<!-- END a -->' after it"):
            _benchdocs.write_section("a", "## A\n\nagain")
        assert docs.read_text() == damaged and list(docs.parent.iterdir()) == [docs]


def test_run_documented_writes_what_the_benchmark_printed(docs, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["bench_x.py", "--write-docs", "--n", "3"])
    seen = []

    def main() -> None:
        seen.append(list(sys.argv))
        print("figure 42")

    _benchdocs.run_documented("x", "X", main)
    assert seen == [["bench_x.py", "--n", "3"]]  # the flag is taken off before the script parses its own
    assert "figure 42" in docs.read_text() and "figure 42" in capsys.readouterr().out


def test_a_benchmark_whose_run_was_cut_short_writes_nothing(docs, monkeypatch, capsys):
    """A training run stopped by Ctrl-C or SIGTERM returns its summary marked interrupted; the benchmark stops
    (exit 130) and its partial figures never replace its section (one did, before `whole`)."""
    _benchdocs.write_section("x", "## X\n\nthe last whole figures")
    before = docs.read_text()
    monkeypatch.setattr(sys, "argv", ["bench_x.py", "--write-docs"])

    class Summary:
        interrupted = True

    def main() -> None:
        print("partial figure 7")
        _benchdocs.whole(Summary())

    with pytest.raises(SystemExit) as stop:
        _benchdocs.run_documented("x", "X", main)
    assert stop.value.code == 130 and docs.read_text() == before
    assert "interrupted; docs/benchmarks.md left as it was" in capsys.readouterr().err
    Summary.interrupted = False
    summary = Summary()
    assert _benchdocs.whole(summary) is summary
