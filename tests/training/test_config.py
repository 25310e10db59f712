"""Training configuration: validation before Ray starts, presets, the critic's normalisation."""

from __future__ import annotations

import pytest

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.training.config import TrainConfig, TrainConfigError, default_run_name, value_normalisation
from smorphi_rl.training.presets import ALGORITHMS, DEFAULT_TIMESTEPS, PRESETS


def test_every_preset_covers_every_algorithm():
    for name, presets in PRESETS.items():
        assert set(presets) == set(ALGORITHMS), name


def test_paper_preset_is_table_1():
    ppo, a3c = PRESETS["paper"]["ppo"], PRESETS["paper"]["impala"]
    assert (ppo.lr, ppo.train_batch_size, ppo.gamma, ppo.lambda_, ppo.num_epochs) == (3e-4, 4096, 0.99, 0.95, 15)
    assert (ppo.grad_clip, ppo.entropy_coeff, ppo.vf_loss_coeff) == (0.5, 0.01, 0.5)
    assert (a3c.lr, a3c.train_batch_size, a3c.gamma, a3c.grad_clip) == (7e-4, 32, 0.99, 0.5)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"algo": "a3c"}, "unknown algorithm 'a3c'"),
        ({"preset": "huge"}, "unknown preset 'huge'"),
        ({"timesteps": 0}, "timesteps must be a positive integer"),
        ({"timesteps": -5}, "timesteps must be a positive integer"),
        ({"seed": -1}, r"seed must be a whole number in \[0, 2\^32-1\], got -1"),
        ({"seed": 2**32}, "seed must be a whole number"),
        ({"max_iterations": 0}, "max_iterations must be a positive integer"),
        ({"overrides": {"minibatch_size": 4000}}, r"minibatch_size \(4000\) must not exceed train_batch_size"),
        ({"algo": "impala", "overrides": {"minibatch_size": 120}}, "must be a multiple of the rollout fragment"),
        ({"overrides": {"minibatch_size": 0}}, "'minibatch_size' must be a positive integer, got 0"),
        ({"max_iterations": 10**20}, "max_iterations 100,000,000,000,000,000,000: at most 1,000,000,000"),
        ({"overrides": {"num_epochs": 0}}, "'num_epochs' must be a positive integer, got 0"),
        ({"overrides": {"train_batch_size": 0}}, "'train_batch_size' must be a positive integer, got 0"),
    ],
)
def test_bad_options_are_named(changes, message):
    with pytest.raises(TrainConfigError, match=message):
        TrainConfig(**changes)


def test_resolved_config_records_hyperparameters():
    doc = TrainConfig(algo="impala", preset="paper").to_dict()
    assert doc["algo"] == "impala" and doc["hyperparameters"]["lr"] == 7e-4
    assert doc["env"]["maps"][0].endswith("map-1.yaml")


def test_default_run_name_is_a_safe_directory_name():
    cfg = TrainConfig(env=EnvConfig(maps=("/x/my map (v2).yaml",)))
    assert default_run_name(cfg, "20260101-000000") == "ppo-my_map_v2_-20260101-000000"
    several = TrainConfig(env=EnvConfig(maps=("/x/map-1.yaml", "/x/map-2.yaml", "/x/map-3.yaml")))
    assert default_run_name(several, "20260101-000000") == "ppo-map-1+2-20260101-000000"


def test_value_normalisation_brackets_random_returns():
    offset, scale = value_normalisation(EnvConfig(reward="paper"), gamma=0.99)
    # R1 of random shapes on map-1 lies around 60..91, over an effective horizon of 100 steps.
    assert 6_000 < offset < 9_100 and 100 < scale < 10_000
    offset, scale = value_normalisation(EnvConfig(reward="level"), gamma=0.99)
    assert abs(offset) < 100 and 100 < scale < 3_000  # standardised R1 (mean 0, spread ~6) over ~100 steps
    offset, scale = value_normalisation(EnvConfig(reward="improvement"), gamma=0.99)
    assert offset == 0 and 1 < scale < 20  # R1 gained, in spreads


def test_each_algorithm_trains_with_our_learner():
    """IMPALA and APPO standardise their v-trace advantages; every learner takes the fused optimiser step."""
    from smorphi_rl.training.config import algorithm_config
    from smorphi_rl.training.learners import CompactPPOLearner, NormalisedAPPOLearner, NormalisedIMPALALearner

    assert algorithm_config(TrainConfig(algo="impala")).learner_class is NormalisedIMPALALearner
    assert algorithm_config(TrainConfig(algo="appo")).learner_class is NormalisedAPPOLearner
    assert algorithm_config(TrainConfig(algo="ppo")).learner_class is CompactPPOLearner


@pytest.mark.parametrize(("algo", "preset", "lam"), [("impala", "fast", 1.0), ("appo", "paper", 1.0)])
def test_the_async_learners_get_vtraces_lambda_through_the_learner_config_dict(algo, preset, lam):
    from smorphi_rl.training.config import algorithm_config
    from smorphi_rl.training.learners import TRACE_LAMBDA_KEY

    assert algorithm_config(TrainConfig(algo=algo, preset=preset)).learner_config_dict[TRACE_LAMBDA_KEY] == lam
    tuned = TrainConfig(algo=algo, preset=preset, overrides={"lambda_": 0.25})
    assert algorithm_config(tuned).learner_config_dict[TRACE_LAMBDA_KEY] == 0.25


def test_ppo_learner_ends_its_pipeline_with_rllibs_gae_then_compact_maps():
    from smorphi_rl import rllib_compat
    from smorphi_rl.env import MorphologyEnv
    from smorphi_rl.training.config import algorithm_config
    from smorphi_rl.training.learners import CompactMaps

    env = MorphologyEnv()
    spaces = {"__env__": (env.observation_space, env.action_space)}
    spaces["default_policy"] = spaces["__env__"]
    learner = algorithm_config(TrainConfig()).build_learner(spaces=spaces)
    learner.build()
    pieces = rllib_compat.learner_pipeline(learner).connectors
    assert type(pieces[-2]).__name__ == "GeneralAdvantageEstimation"
    assert isinstance(pieces[-1], CompactMaps)


def test_a_final_learning_rate_makes_a_linear_schedule_over_the_budget():
    from smorphi_rl.training.config import algorithm_config

    cfg = TrainConfig(timesteps=30_000, overrides={"lr": 2e-3, "lr_final": 1e-4})
    assert algorithm_config(cfg).lr == [[0, 2e-3], [30_000, 1e-4]]
    impala = PRESETS["fast"]["impala"]
    assert algorithm_config(TrainConfig(algo="impala")).lr == [[0, impala.lr], [DEFAULT_TIMESTEPS, impala.lr_final]]
    assert algorithm_config(TrainConfig(algo="impala", preset="paper")).lr == 7e-4  # constant: no lr_final


def test_a_final_entropy_coefficient_makes_a_linear_schedule_over_the_budget():
    from smorphi_rl.training.config import algorithm_config

    cfg = TrainConfig(algo="appo", timesteps=400_000, overrides={"entropy_coeff": 0.01, "entropy_final": 0.0})
    assert algorithm_config(cfg).entropy_coeff == [[0, 0.01], [400_000, 0.0]]
    assert algorithm_config(TrainConfig(algo="appo", preset="paper")).entropy_coeff == 0.01  # constant
    with pytest.raises(TrainConfigError, match="entropy_final"):
        TrainConfig(overrides={"entropy_final": -0.01})


def test_a_knee_bends_the_schedule_at_its_share_of_the_budget():
    from smorphi_rl.training.config import algorithm_config

    cfg = TrainConfig(timesteps=400_000, overrides={"lr": 1e-3, "lr_final": 5e-5, "lr_knee": 1e-4, "lr_knee_at": 0.625})
    assert algorithm_config(cfg).lr == [[0, 1e-3], [250_000, 1e-4], [400_000, 5e-5]]
    with pytest.raises(TrainConfigError, match="lr_knee_at"):
        TrainConfig(overrides={"lr_knee_at": 1.5})
    with pytest.raises(TrainConfigError, match="needs lr_final"):
        TrainConfig(preset="paper", overrides={"lr_knee": 1e-4})  # the paper's rate is constant
    with pytest.raises(TrainConfigError, match="needs lr_final"):
        TrainConfig(overrides={"lr_knee": 1e-4, "lr_knee_at": 0})
    with pytest.raises(TrainConfigError, match="lr_knee, which is not set"):
        TrainConfig(overrides={"lr_knee_at": 0.5})


def test_appos_circular_buffer_is_a_tunable_hyperparameter_of_appo_alone():
    from smorphi_rl.training.config import algorithm_config

    tuned = TrainConfig(algo="appo", overrides={"circular_buffer_batches": 1, "circular_buffer_passes": 3})
    built = algorithm_config(tuned)
    assert (built.circular_buffer_num_batches, built.circular_buffer_iterations_per_batch) == (1, 3)
    default = algorithm_config(TrainConfig(algo="appo"))
    assert (default.circular_buffer_num_batches, default.circular_buffer_iterations_per_batch) == (8, 2)  # RLlib's
    with pytest.raises(TrainConfigError, match="appo's; ppo has none"):
        TrainConfig(overrides={"circular_buffer_batches": 1})
    with pytest.raises(TrainConfigError, match="'circular_buffer_passes' must be a positive integer, got 0"):
        TrainConfig(algo="appo", overrides={"circular_buffer_passes": 0})


def test_appos_learner_queue_replaces_the_circular_buffer_and_pg_lambda_reaches_the_learner():
    from smorphi_rl.training.config import algorithm_config
    from smorphi_rl.training.learners import PG_LAMBDA_KEY, TRACE_LAMBDA_KEY

    built = algorithm_config(TrainConfig(algo="appo", overrides={"learner_queue": 2, "pg_lambda": 0.5}))
    assert (built.use_circular_buffer, built.simple_queue_size) == (False, 2)
    assert built.learner_config_dict[PG_LAMBDA_KEY] == 0.5 and built.learner_config_dict[TRACE_LAMBDA_KEY] == 1.0
    default = algorithm_config(TrainConfig(algo="impala"))
    assert default.learner_config_dict[PG_LAMBDA_KEY] == 1.0  # IMPALA's advantage
    assert algorithm_config(TrainConfig(algo="appo")).use_circular_buffer  # RLlib's
    with pytest.raises(TrainConfigError, match="'learner_queue' must be a positive integer, got 0"):
        TrainConfig(algo="appo", overrides={"learner_queue": 0})
    with pytest.raises(TrainConfigError, match="'frozen_critic' must be 0 or 1, got 2"):
        TrainConfig(algo="appo", overrides={"frozen_critic": 2})
    with pytest.raises(TrainConfigError, match="'pg_lambda' must be a number in"):
        TrainConfig(algo="appo", overrides={"pg_lambda": 1.5})
    with pytest.raises(TrainConfigError, match="impala and appo's; ppo has none"):
        TrainConfig(overrides={"pg_lambda": 0.5})


@pytest.mark.parametrize("stem", ["trained", "kept", "starts", "median_gap", "design_median_gap_pct"])
def test_a_map_named_like_an_evaluation_figure_is_refused(tmp_path, stem):
    """Its summary sits beside the pooled figures under eval/: one would overwrite the other."""
    from pathlib import Path

    source = Path(__file__).resolve().parents[2] / "maps"
    (tmp_path / f"{stem}.yaml").write_text((source / "map-1.yaml").read_text())
    (tmp_path / "map-1.pgm").write_bytes((source / "map-1.pgm").read_bytes())
    with pytest.raises(TrainConfigError, match=f"a map named '{stem}' would be mistaken"):
        TrainConfig(env=EnvConfig.from_dict({"maps": [str(tmp_path / f"{stem}.yaml")]}))


@pytest.mark.parametrize("where", ["maps", "eval_maps"])
def test_two_maps_of_one_name_are_refused(tmp_path, where):
    """Each map's optimum, evaluation and plots are keyed by its name: map-2 filed as map-1 replaced map-1's."""
    from pathlib import Path

    source = Path(__file__).resolve().parents[2] / "maps"
    (tmp_path / "map-1.yaml").write_text((source / "map-2.yaml").read_text())
    (tmp_path / "map-2.pgm").write_bytes((source / "map-2.pgm").read_bytes())
    both = [str(source / "map-1.yaml"), str(tmp_path / "map-1.yaml")]
    with pytest.raises(TrainConfigError, match="share the name 'map-1'"):
        if where == "maps":
            TrainConfig(env=EnvConfig.from_dict({"maps": both}))
        else:
            TrainConfig(env=EnvConfig.from_dict({"maps": both[:1]}), eval_maps=tuple(both))
    TrainConfig(env=EnvConfig.from_dict({"maps": [both[0], both[0]]}))  # one map twice is one map


def test_the_kl_penalty_is_a_tunable_hyperparameter_of_ppo_and_appo():
    from smorphi_rl.training.config import algorithm_config

    on = algorithm_config(TrainConfig(algo="appo", overrides={"kl_coeff": 0.2}))
    assert (on.use_kl_loss, on.kl_coeff) == (True, 0.2)
    assert not algorithm_config(TrainConfig(algo="appo")).use_kl_loss  # RLlib's APPO: off
    ppo = algorithm_config(TrainConfig())
    assert (ppo.use_kl_loss, ppo.kl_coeff) == (True, 0.2)  # RLlib's PPO: on
    assert not algorithm_config(TrainConfig(overrides={"kl_coeff": 0})).use_kl_loss
    with pytest.raises(TrainConfigError, match="ppo and appo's; impala has none"):
        TrainConfig(algo="impala", overrides={"kl_coeff": 0.2})


def test_a_numpy_integer_seed_is_kept_as_an_int():
    """The Python API: a NumPy seed passed the check, then config.json could not be written (after Ray started)."""
    import json

    import numpy as np

    cfg = TrainConfig(seed=np.int64(3))
    assert type(cfg.seed) is int and json.loads(json.dumps(cfg.to_dict()))["seed"] == 3
