"""The version gate: one warning line for a Ray or torch other than the tested ones, nothing otherwise."""

from __future__ import annotations

from smorphi_rl.training import versions


def test_the_tested_versions_are_installed_here():
    assert versions.version_warning() is None, versions.version_warning()


def test_another_ray_is_named_in_one_line(monkeypatch):
    monkeypatch.setattr(versions, "installed", lambda name: "2.99.0" if name == "ray" else versions.TESTED[name])
    line = versions.version_warning()
    assert line is not None and "\n" not in line and "ray 2.99.0" in line and "ray 2.60.0" in line
