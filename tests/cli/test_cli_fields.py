"""Options made from configuration fields: one home for each default and its explanation."""

import argparse

from smorphi_rl.cli import build_parser
from smorphi_rl.cli.fields import UNSET, option
from smorphi_rl.config_fields import field_docs
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.search.config import SearchConfig
from smorphi_rl.training.config import TrainConfig


def test_field_docs_are_the_strings_under_the_fields():
    docs = field_docs(EnvConfig)
    assert docs["max_steps"] == "Episode length (truncation)."
    assert docs["path_term"].startswith("How w2 charges the path: `moves` (per tile move, the paper's) or")
    assert "\n" not in docs["path_term"] and "  " not in docs["path_term"]
    assert "maps" in docs and "planning" not in docs  # a property is not a field


def test_an_option_takes_type_default_and_help_from_its_field():
    parser = argparse.ArgumentParser()
    option(parser, EnvConfig, "max_steps")
    option(parser, EnvConfig, "w2", unset=True)
    assert parser.parse_args([]).max_steps == EnvConfig.max_steps
    assert parser.parse_args(["--max-steps", "7"]).max_steps == 7
    assert parser.parse_args([]).w2 is UNSET and parser.parse_args(["--w2", "0.5"]).w2 == 0.5
    text = parser.format_help()
    assert "Episode length (truncation). (default: 200)" in text
    assert "(default: 0.1)" in " ".join(text.split())  # an unset option still shows the field's default


def test_the_command_lines_defaults_are_the_configurations():
    parser = build_parser()
    train = parser.parse_args(["train"])
    defaults = TrainConfig()
    for name in ("timesteps", "seed", "preset", "checkpoint_every", "envs_per_runner", "eval_every",
                 "eval_starts", "select_starts", "record_every"):  # fmt: skip
        assert getattr(train, name) == getattr(defaults, name), name
    assert train.env_runners is None and train.reward is None  # applied downstream (the preset, the env)
    from smorphi_rl.cli.train import train_setup

    assert train.algo is None and train_setup(train)[0] == defaults.algo  # or the pretrained policy's
    nsga2 = parser.parse_args(["search", "nsga2"])
    assert (nsga2.pop, nsga2.generations, nsga2.seed) == (SearchConfig.pop, SearchConfig.generations, 0)
    assert parser.parse_args(["search", "exhaustive"]).step == SearchConfig.step
    assert parser.parse_args(["evaluate", "--angles", "1", "2", "3"]).block_side == EnvConfig.block_side_m


def test_an_error_naming_a_field_names_the_flag_the_user_gave(capsys, tmp_path):
    """`--w1 0` was refused as "env_config 'w1' must be ...": the user typed a flag, not a configuration key."""
    from smorphi_rl.cli import main

    cases = {
        ("--w1", "0"): "--w1 must be",
        ("--checkpoint-every", "0"): "error: --checkpoint-every must be a positive integer, got 0",
        ("--envs-per-runner", "0"): "error: --envs-per-runner must be a positive integer, got 0",
    }
    for given, message in cases.items():
        assert main(["train", *given, "--log-dir", str(tmp_path / "logs")]) == 1
        assert message in capsys.readouterr().err
    assert not (tmp_path / "logs").exists()
