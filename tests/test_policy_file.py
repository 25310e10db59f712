"""Exported policy folders: what `read_policy` refuses, in one line, before any weight is used."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import pytest

import smorphi_rl
from smorphi_rl.policy_file import PolicyFileError, read_policy

DESIGNER = Path(smorphi_rl.__file__).parent / "policies" / "designer"


@pytest.mark.parametrize("entry", ["README.txt", "sub/"])
def test_an_archive_entry_that_is_not_an_array_is_named(tmp_path, entry):
    """numpy hands a non-.npy entry over as raw bytes; reading its dtype was an AttributeError traceback."""
    folder = tmp_path / "policy"
    shutil.copytree(DESIGNER, folder)
    with zipfile.ZipFile(folder / "weights.npz", "a") as archive:
        archive.writestr(entry, "" if entry.endswith("/") else "hi")
    with pytest.raises(PolicyFileError, match=f"weights.npz: entry {entry} is not an array"):
        read_policy(folder)


def test_an_exported_policy_exported_again_keeps_what_was_said_of_it(tmp_path, capsys):
    """The same weights: its env steps, the designer's `accepts` and `held_out` and its source travel (they were
    dropped, and `design --policy` then described the copy without its training)."""
    import json

    from smorphi_rl.cli import main

    assert main(["export-policy", "--checkpoint", str(DESIGNER), "--out", str(tmp_path / "again")]) == 0
    again, shipped = (json.loads((d / "policy.json").read_text()) for d in (tmp_path / "again", DESIGNER))
    assert again == shipped
    assert main(["export-policy", "--checkpoint", str(DESIGNER), "--out", str(tmp_path / "said"), "--command",
                 "my words"]) == 0  # fmt: skip
    said = read_policy(tmp_path / "said").about
    assert said["command"] == "my words" and said["held_out"] == shipped["held_out"]
