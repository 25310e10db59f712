"""Typed training configuration -> an RLlib AlgorithmConfig for PPO, IMPALA or APPO.

Validated once, before Ray starts; the presets here are the only place hyperparameters live.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.errors import SmorphiError
from smorphi_rl.inputs import check_seed, first_repeat
from smorphi_rl.policy_file import MAX_FREQUENCIES
from smorphi_rl.protocol import EVAL_EVERY, EVAL_STARTS
from smorphi_rl.training.presets import (
    ALGORITHMS,
    ANGLE_FREQUENCIES,
    DEFAULT_TIMESTEPS,
    ENVS_PER_RUNNER,
    LAYOUT,
    PRESETS,
    Preset,
)

TUNE_ENV_NAME = "smorphi_rl_morphology"
"""The env's name in Ray Tune's registry (a Tune config names the env by this string)."""
CPUS_PER_ENV_RUNNER = 0.5
"""Two runners plus the trial's own process fit in 2 CPUs (1 CPU each never starts on 2 cores)."""
CPUS_FOR_TRIAL = 1.0
"""The trial's own process: the learner, and the local env runner when there are no remote ones."""


DEFAULT_RECORD_EVERY = 100
"""Record every 100th episode of each env by default: a vector env of 32 then writes about one file per
3,200 episodes' worth of each env's share, and the run slows by about 0.5 % (a recorded episode's sampling costs
54 % more; docs/decisions.md)."""


MAX_EVAL_STARTS = 1000
"""Each evaluation rolls every start out (about 10 ms a start): more would stall the run at every evaluation."""
MAX_ENVS_PER_RUNNER = 1024
"""Each env keeps its own state and a runner steps them all at once: beyond this, memory, not speed, grows."""
MAX_DESIGN_BUDGET = 100_000


MAX_TIMESTEPS = 10**9
"""A training budget beyond this is a typo, not a run (weeks on a laptop; split it across runs on a cluster)."""


class TrainConfigError(SmorphiError):
    """A training option that is unknown or out of range."""


@dataclass(frozen=True)
class TrainConfig:
    """One training run, as the CLI or a sweep file gives it."""

    algo: str = "ppo"
    """Algorithm: ppo, impala (serves the paper's A3C) or appo."""
    env: EnvConfig = field(default_factory=EnvConfig)
    timesteps: int = DEFAULT_TIMESTEPS
    """Env steps to train for."""
    seed: int = 0
    """Seeds the learner, every env runner and every sub-env (independent streams)."""
    preset: str = "fast"
    """Hyperparameters: fast (2 cores) or paper (Table 1)."""
    num_env_runners: int | None = None
    """Remote env runners; None: the preset's layout (2; 0 samples in the trial process)."""
    envs_per_runner: int = ENVS_PER_RUNNER
    """Envs each env runner steps as one vector env (one policy forward pass for all of them)."""
    checkpoint_every: int = 10
    """Checkpoint every this many iterations (and always at the end)."""
    top_k: int = 8
    """Best shapes kept in the run's top-k table."""
    pretrained: str | None = None
    """Checkpoint (or trial or run directory, or exported policy) to start from: fine-tuning, the paper's transfer.
    `train` then takes the policy's algorithm and env settings, but its floors and start point, unless given."""
    max_iterations: int | None = None
    """Also stop after this many training iterations (tests and smoke runs); None: the env-step budget only."""
    overrides: dict[str, float] = field(default_factory=dict)
    """Hyperparameters that replace the preset's (a sweep's search space), by Preset field name."""
    eval_every: int = EVAL_EVERY
    """Evaluate the greedy policy from the protocol's fixed starts every this many iterations (0: never)."""
    eval_starts: int = EVAL_STARTS
    """Fixed seeded start shapes per evaluated map (`eval_maps`, else the training maps) in each evaluation."""
    select_starts: int = EVAL_STARTS
    """End on the run's best evaluated policy, chosen on this many other seeded starts per map (0: the last)."""
    record_every: int = DEFAULT_RECORD_EVERY
    """Record every Nth episode of each env to MCAP under the run's episodes/ folder; 0: no recording."""
    design_budget: int = 0
    """Each evaluation also runs the designer (`design.py`) on the evaluated maps with this many planner
    evaluations and reports its gap to each optimum (eval/design_...); 0: off."""
    eval_maps: tuple[str, ...] = ()
    """Maps the evaluation protocol runs on (files, folders or globs; their exact optima are computed first);
    empty: the training maps that are files. A generalist policy is evaluated on held-out floors this way."""

    def __post_init__(self) -> None:
        if self.pretrained is not None:  # trials run in their own folders: a relative path would not be found
            object.__setattr__(self, "pretrained", str(Path(self.pretrained).resolve()))
        if self.eval_maps:
            from smorphi_rl.map_sources import MapSourceError, is_generator, resolve

            if any(is_generator(str(m)) for m in self.eval_maps):
                raise TrainConfigError("eval_maps must be map files, folders or globs (an optimum needs a fixed map)")
            try:
                object.__setattr__(self, "eval_maps", resolve([str(m) for m in self.eval_maps]))
            except MapSourceError as exc:
                raise TrainConfigError(f"eval_maps: {exc}") from None
            files = [str(Path(m).resolve()) for m in self.eval_maps]
            twice = first_repeat(files)
            if twice is not None:  # its starts would count twice in every pooled figure
                raise TrainConfigError(f"eval_maps: {files[twice]} is named twice (by two entries, or a folder or "
                                       "glob and a file)")  # fmt: skip
        from smorphi_rl.map_sources import name_clash
        from smorphi_rl.protocol import clashing_map_name

        clash = name_clash((*self.env.map_files, *self.evaluation_maps))  # optima, figures, digests keyed by name
        if clash is not None:
            raise TrainConfigError(f"maps {clash[0]} and {clash[1]} share the name {Path(clash[1]).stem!r}, which "
                                   "keys each map's optimum and figures: rename one")  # fmt: skip
        for path in self.evaluation_maps:
            if clashing_map_name(Path(path).stem):
                raise TrainConfigError(f"{path}: a map named {Path(path).stem!r} would be mistaken for the "
                                       "evaluation's figure of that name: rename the map file")  # fmt: skip
        if self.algo not in ALGORITHMS:
            raise TrainConfigError(f"unknown algorithm '{self.algo}' (choose from {', '.join(ALGORITHMS)})")
        if self.preset not in PRESETS:
            raise TrainConfigError(f"unknown preset '{self.preset}' (choose from {', '.join(PRESETS)})")
        for name in ("timesteps", "envs_per_runner", "checkpoint_every", "top_k", "eval_starts"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise TrainConfigError(f"{name} must be a positive integer, got {value!r}")
        if self.timesteps > MAX_TIMESTEPS:
            raise TrainConfigError(f"timesteps {self.timesteps:,}: at most {MAX_TIMESTEPS:,} (days of training on 2 "
                                   "cores already: split a longer one across runs on a cluster)")  # fmt: skip
        runners = self.num_env_runners
        if runners is not None and (isinstance(runners, bool) or not isinstance(runners, int) or runners < 0):
            raise TrainConfigError(f"env runners must be 0 (sample in the trial process) or more, got {runners!r}")
        if self.max_iterations is not None and (not isinstance(self.max_iterations, int) or self.max_iterations < 1):
            raise TrainConfigError(f"max_iterations must be a positive integer, got {self.max_iterations!r}")
        if self.max_iterations is not None and self.max_iterations > MAX_TIMESTEPS:  # an iteration is 1+ env steps
            raise TrainConfigError(f"max_iterations {self.max_iterations:,}: at most {MAX_TIMESTEPS:,}, the most env "
                                   "steps a run takes")  # fmt: skip
        object.__setattr__(self, "seed", check_seed(self.seed, error=TrainConfigError))  # a NumPy integer: an int
        for name in ("eval_every", "select_starts", "record_every", "design_budget"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise TrainConfigError(f"{name} must be a non-negative integer (0: off), got {value!r}")
        for name, most in (("eval_starts", MAX_EVAL_STARTS), ("select_starts", MAX_EVAL_STARTS),
                           ("envs_per_runner", MAX_ENVS_PER_RUNNER), ("design_budget", MAX_DESIGN_BUDGET)):  # fmt: skip
            if getattr(self, name) > most:
                raise TrainConfigError(f"{name} must be at most {most:,}, got {getattr(self, name):,}")
        check_overrides(self.algo, self.overrides)
        hp = self.hyperparameters
        if hp.lr_knee is not None and (hp.lr_final is None or not 0 < hp.lr_knee_at < 1):
            raise TrainConfigError(
                f"lr_knee bends the fall to lr_final: it needs lr_final and 0 < lr_knee_at < 1 "
                f"(lr_final {hp.lr_final}, lr_knee_at {hp.lr_knee_at})"
            )
        if "lr_knee_at" in self.overrides and hp.lr_knee is None:
            raise TrainConfigError("lr_knee_at places lr_knee, which is not set")
        if hp.minibatch_size is not None:
            if hp.minibatch_size > hp.train_batch_size:
                raise TrainConfigError(
                    f"minibatch_size ({hp.minibatch_size}) must not exceed train_batch_size ({hp.train_batch_size})"
                )
            fragment = hp.rollout_fragment_length
            if self.algo != "ppo" and isinstance(fragment, int) and hp.minibatch_size % fragment:
                raise TrainConfigError(
                    f"{self.algo}: minibatch_size ({hp.minibatch_size}) must be a multiple of the rollout fragment "
                    f"length ({fragment})"
                )

    @property
    def evaluation_maps(self) -> tuple[str, ...]:
        """The maps the protocol evaluates on: `eval_maps`, else the training maps that are files."""
        return self.eval_maps or self.env.map_files

    @property
    def env_runners(self) -> int:
        """Remote env runners of this run: the option, else the preset's layout."""
        return self.hyperparameters.env_runners if self.num_env_runners is None else self.num_env_runners

    @property
    def cpus(self) -> float:
        """CPUs one trial of this run asks for: its own process plus each remote env runner's share."""
        return CPUS_FOR_TRIAL + CPUS_PER_ENV_RUNNER * self.env_runners

    @property
    def hyperparameters(self) -> Preset:
        """The preset's hyperparameters with the overrides applied."""
        return replace(PRESETS[self.preset][self.algo], **self.overrides)  # type: ignore[arg-type]

    def with_env(self, **changes: Any) -> TrainConfig:
        return replace(self, env=replace(self.env, **changes))

    def to_dict(self) -> dict[str, Any]:
        """The resolved configuration, as written next to the results."""
        out = asdict(self)
        out["hyperparameters"] = asdict(self.hyperparameters)
        return out


FRACTIONS = ("gamma", "lambda_", "clip_param", "pg_lambda", "frozen_critic", "lr_knee_at")
"""Hyperparameters that must lie in [0, 1]."""
USED_BY = {
    "clip_param": ("ppo", "appo"),
    "kl_coeff": ("ppo", "appo"),
    "pg_lambda": ("impala", "appo"),
    "target_update_freq": ("appo",),
    "circular_buffer_batches": ("appo",),
    "circular_buffer_passes": ("appo",),
    "learner_queue": ("appo",),
    "frozen_critic": ("appo",),
}
"""Hyperparameters only some algorithms have (the others take every Preset field)."""
AT_LEAST_ONE = (
    "train_batch_size",
    "num_epochs",
    "minibatch_size",
    "circular_buffer_batches",
    "circular_buffer_passes",
    "learner_queue",
)
"""Hyperparameters that must be at least 1 (a batch, a pass or a buffer of none trains on nothing)."""


INTEGER_HYPERPARAMETERS = (
    "train_batch_size",
    "num_epochs",
    "minibatch_size",
    "policy_angle_frequencies",
    "circular_buffer_batches",
    "circular_buffer_passes",
    "learner_queue",
    "frozen_critic",
)
"""Preset fields that take whole numbers."""


def check_overrides(algo: str, overrides: dict[str, Any]) -> None:
    """Every override names a hyperparameter that `algo` uses, with a positive number (gamma, lambda_ <= 1)."""
    known = {f.name for f in fields(Preset)} - set(LAYOUT)
    for name, value in overrides.items():
        if name not in known:
            raise TrainConfigError(f"unknown hyperparameter '{name}' (known: {', '.join(sorted(known))})")
        if algo not in USED_BY.get(name, (algo,)):
            raise TrainConfigError(f"hyperparameter '{name}' is {' and '.join(USED_BY[name])}'s; {algo} has none")
        integer = name in INTEGER_HYPERPARAMETERS
        least = 1 if name in AT_LEAST_ONE else 0
        ok = not isinstance(value, bool) and isinstance(value, int if integer else int | float) and value >= least
        if not ok or (name in FRACTIONS and not 0 <= value <= 1):
            kind = (
                "a positive integer"
                if least
                else "0 or 1"
                if integer and name in FRACTIONS
                else "a non-negative integer"
                if integer
                else "a number in [0, 1]"
                if name in FRACTIONS
                else "a non-negative number"
            )
            raise TrainConfigError(f"hyperparameter '{name}' must be {kind}, got {value!r}")
        if name == "policy_angle_frequencies" and value > MAX_FREQUENCIES:  # every loader refuses a wider policy
            raise TrainConfigError(f"hyperparameter '{name}' must be at most {MAX_FREQUENCIES}, got {value!r}")


def learning_rate(hp: Preset, timesteps: int) -> float | list[list[float]]:
    """RLlib's `lr`: the constant rate, or the piecewise-linear schedule in env steps from `lr` to `lr_final`
    (through `lr_knee` at `lr_knee_at` of the budget when set)."""
    if hp.lr_final is None:
        return hp.lr
    knee = [] if hp.lr_knee is None else [[round(hp.lr_knee_at * timesteps), hp.lr_knee]]
    return [[0, hp.lr], *knee, [timesteps, hp.lr_final]]


def entropy_coefficient(hp: Preset, timesteps: int) -> float | list[list[float]]:
    """RLlib's `entropy_coeff`: the constant, or the linear schedule in env steps to `entropy_final`."""
    if hp.entropy_final is None:
        return hp.entropy_coeff
    return [[0, hp.entropy_coeff], [timesteps, hp.entropy_final]]


def value_normalisation(env: EnvConfig, gamma: float, samples: int = 256) -> tuple[float, float]:
    """(offset, scale) for the critic, V = offset + scale * head, from R1 of random shapes on the maps.

    Starting the critic at the random-shape return level and scaling its head to the spread lets it
    learn in a few iterations instead of a few hundred. Returns by reward mode: `paper`, R1 a step
    over ~1/(1-gamma) steps (thousands); `level`, the same in standard units (centred on 0);
    `peak`, the same in its units; `improvement`, the R1 gained in sigma_map units; `commit`, one shape's R1
    in sigma_map units."""
    import numpy as np

    from smorphi_rl.env import map_r1_stats, peak_reward
    from smorphi_rl.env_config import RewardMode

    rng = np.random.default_rng(0)
    thetas = rng.integers(0, 181, size=(samples, 3)).astype(np.float64)
    per_map = []
    for grid_map in sample_maps(env):
        batch = env.planning.evaluator(grid_map).evaluate_many(thetas)
        weights = env.weights_on(grid_map)
        values = weights.r1(batch.P_c, batch.P_len)
        if env.reward == RewardMode.PEAK.value:
            stats = map_r1_stats(grid_map, weights, env.planning)
            values = peak_reward(values, stats.q90, stats.sigma)
        elif env.reward != RewardMode.PAPER.value:
            stats = map_r1_stats(grid_map, weights, env.planning)
            values = (values - (stats.mu if env.reward == RewardMode.LEVEL.value else 0.0)) / stats.sigma
        per_map.append(values)
    values = np.concatenate(per_map)
    spread = max(float(values.max() - values.min()), 1e-3)
    if env.reward == RewardMode.IMPROVEMENT.value:
        return 0.0, spread
    if env.reward == RewardMode.COMMIT.value:
        return float(values.mean()), spread
    horizon = min(1.0 / (1.0 - gamma), float(env.max_steps)) if gamma < 1 else float(env.max_steps)
    return float(values.mean()) * horizon, spread * horizon


GENERATED_SAMPLE = 8
"""Floors of each generator that stand for it where figures over the maps are needed (the critic's scale)."""


def sample_maps(env: EnvConfig) -> list[Any]:
    """The env's map files, and the first GENERATED_SAMPLE floors of each of its generators."""
    from smorphi_rl.floorplans import generate_floor
    from smorphi_rl.map_sources import generators
    from smorphi_rl.maps import load_map

    maps = [load_map(p) for p in env.map_files]
    for source in generators(env.maps):
        seeds = range(source.lo, min(source.hi, source.lo + GENERATED_SAMPLE))
        maps += [generate_floor(source.kind, seed) for seed in seeds]
    return maps


EPISODES_DIR = "episodes"
"""The folder under a run (or trial) directory that holds its MCAP recordings."""


def recording_settings(cfg: TrainConfig, run_dir: Path, run: str) -> dict[str, Any] | None:
    """The RecordingConfig dict for the env runners of one run, or None when recording is off."""
    if not cfg.record_every:
        return None
    from smorphi_rl.recording import RecordingConfig

    meta = {"run": run, "algorithm": cfg.algo, "seed": str(cfg.seed), "config": json.dumps(cfg.to_dict())}
    return RecordingConfig(str((run_dir / EPISODES_DIR).resolve()), every=cfg.record_every, metadata=meta).to_dict()


def default_run_name(cfg: TrainConfig, stamp: str) -> str:
    """`<algo>-<first map>-<stamp>`, or `<algo>-<first map>+<N more>-<stamp>` on several maps (a folder of them
    named after its first alone looked like a run on that map), safe as a directory name."""
    from smorphi_rl.rundir import safe_name

    first = cfg.env.maps[0]
    label = first.split(":")[1] if first.startswith("generate:") else Path(first).name.removesuffix(".yaml")
    more = f"+{len(cfg.env.maps) - 1}" if len(cfg.env.maps) > 1 else ""
    return safe_name(f"{cfg.algo}-{label}{more}-{stamp}")


def make_env(env_config: dict[str, Any] | None) -> Any:
    """RLlib's env creator: `vector_env.make_env`, each env wrapped for recording when env_config carries a
    RecordingConfig (the recording package reads the env, so the env does not import it)."""
    from smorphi_rl import vector_env

    recording = (env_config or {}).get(vector_env.RECORDING_KEY)
    if not recording:
        return vector_env.make_env(env_config)
    from smorphi_rl.recording import RecordingConfig, RecordingWrapper

    config = RecordingConfig(**recording)
    return vector_env.make_env(env_config, lambda env, worker: RecordingWrapper(env, config, worker_index=worker))


def register_env() -> None:
    """Register the env with Ray Tune under TUNE_ENV_NAME (safe to call again)."""
    from ray.tune.registry import register_env as tune_register

    tune_register(TUNE_ENV_NAME, make_env)


@contextmanager
def standalone_algorithm(config: Any) -> Iterator[Any]:
    """An Algorithm built outside Tune (the benchmarks, tests), stopped on leaving. RLlib makes it an empty log
    folder under ~/ray_results and Ray names no other place outside Tune; that folder is removed again, and
    ~/ray_results with it if this made it and it is empty."""
    from ray.train.constants import DEFAULT_STORAGE_PATH

    results = Path(DEFAULT_STORAGE_PATH)
    made = not results.exists()
    algo = config.build_algo()
    try:
        yield algo
    finally:
        logdir = Path(algo.logdir)
        algo.stop()
        for folder in (logdir, results) if made else (logdir,):
            try:
                folder.rmdir()  # only when empty: nothing anybody wrote is removed
            except OSError:
                break


def policy_layout(pretrained: str | None, frequencies: int) -> int:
    """The angle frequencies the policy net sees: the preset's, or the pretrained checkpoint's (a policy is
    fine-tuned in the layout it was trained with; one written before the key existed had 8)."""
    if pretrained is None:
        return frequencies
    from smorphi_rl.training.checkpoints import find_checkpoint, load_module

    config = load_module(find_checkpoint(pretrained)).model_config or {}
    return int(config.get("policy_angle_frequencies", ANGLE_FREQUENCIES))


def algorithm_config(
    cfg: TrainConfig, callbacks: type | None = None, recording: dict[str, Any] | None = None, lean: bool = True
) -> Any:
    """The RLlib AlgorithmConfig (new API stack) for `cfg`: 2 env runners, our module and callbacks
    (`callbacks`, default MorphologyCallbacks; fine-tuning passes its own subclass). `recording`, a
    RecordingConfig dict, makes the env runners record episodes to MCAP. `lean`: the env runners use our
    connector pipelines (`sampling.py`), which sample exactly what RLlib's default ones do, faster. The env's name
    is registered here, so that `algorithm_config(cfg).build_algo()` works outside Tune too."""
    from ray.rllib.algorithms.appo import APPOConfig
    from ray.rllib.algorithms.impala import IMPALAConfig
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec

    from smorphi_rl.training.callbacks import MorphologyCallbacks
    from smorphi_rl.training.learners import FROZEN_CRITIC_KEY, LEARNERS, PG_LAMBDA_KEY, TRACE_LAMBDA_KEY
    from smorphi_rl.training.module import MorphologyModule
    from smorphi_rl.training.sampling import LEAN_SAMPLING
    from smorphi_rl.vector_env import RECORDING_KEY, SEED_KEY

    register_env()
    hp = cfg.hyperparameters
    offset, scale = value_normalisation(cfg.env, hp.gamma)
    config_cls = {"ppo": PPOConfig, "impala": IMPALAConfig, "appo": APPOConfig}[cfg.algo]
    env_dict = cfg.env.to_dict()
    training: dict[str, Any] = {
        "lr": learning_rate(hp, cfg.timesteps),
        "gamma": hp.gamma,
        "entropy_coeff": entropy_coefficient(hp, cfg.timesteps),
        "vf_loss_coeff": hp.vf_loss_coeff,
        "grad_clip": hp.grad_clip,
        "grad_clip_by": "norm",  # per tensor: the value net's large gradients never shrink the policy's
        "train_batch_size_per_learner": hp.train_batch_size,
        "num_epochs": hp.num_epochs,
        "minibatch_size": hp.minibatch_size,
    }
    # PPO's lambda is RLlib's; v-trace's settings reach our learners through RLlib's public learner_config_dict
    pg_lambda = 1.0 if hp.pg_lambda is None else hp.pg_lambda
    trace = {} if cfg.algo == "ppo" else {TRACE_LAMBDA_KEY: hp.lambda_, PG_LAMBDA_KEY: pg_lambda,
                                          FROZEN_CRITIC_KEY: hp.frozen_critic}  # fmt: skip
    if cfg.algo == "ppo":
        # returns are in the thousands; a value clip at 10 would freeze the critic
        training |= {"lambda_": hp.lambda_, "vf_clip_param": math.inf}
    if hp.clip_param is not None:  # PPO's and APPO's only (check_overrides)
        training["clip_param"] = hp.clip_param
    if hp.kl_coeff is not None:  # PPO's and APPO's only
        training |= {"use_kl_loss": hp.kl_coeff > 0, "kl_coeff": hp.kl_coeff}
    if hp.target_update_freq is not None:  # APPO's only
        training["target_network_update_freq"] = hp.target_update_freq
    if hp.circular_buffer_batches is not None:  # APPO's only
        training["circular_buffer_num_batches"] = hp.circular_buffer_batches
    if hp.circular_buffer_passes is not None:
        training["circular_buffer_iterations_per_batch"] = hp.circular_buffer_passes
    if hp.learner_queue is not None:
        training |= {"use_circular_buffer": False, "simple_queue_size": hp.learner_queue}
    config = (
        config_cls()
        .environment(
            TUNE_ENV_NAME,
            env_config=env_dict | {SEED_KEY: cfg.seed} | ({RECORDING_KEY: recording} if recording else {}),
            # discrete actions: nothing to unsquash or clip, and the pass deep-copies every action (8 % of sampling)
            normalize_actions=False,
            clip_actions=False,
        )
        .framework("torch")
        .env_runners(
            num_env_runners=cfg.env_runners,
            num_envs_per_env_runner=cfg.envs_per_runner,
            gym_env_vectorize_mode="vector_entry_point",  # our MorphologyVectorEnv (smorphi_rl/vector_env.py)
            num_cpus_per_env_runner=CPUS_PER_ENV_RUNNER,  # type: ignore[arg-type]  # RLlib takes fractions
            rollout_fragment_length=hp.rollout_fragment_length,
            **(LEAN_SAMPLING if lean else {}),  # type: ignore[arg-type]  # RLlib types the connector callables loosely
        )
        .learners(num_learners=0, learner_class=LEARNERS[cfg.algo], learner_config_dict=trace)  # learners.py
        .training(**training)
        .rl_module(
            rl_module_spec=RLModuleSpec(
                module_class=MorphologyModule,
                model_config={
                    "value_offset": offset,
                    "value_scale": scale,
                    "policy_angle_frequencies": policy_layout(cfg.pretrained, hp.policy_angle_frequencies),
                    "env_config": env_dict,
                    "algorithm": cfg.algo,
                },
            )
        )
        .callbacks(callbacks or MorphologyCallbacks)
        .reporting(min_time_s_per_iteration=hp.min_time_s_per_iteration or None)
        .debugging(seed=cfg.seed)
    )
    return config
