"""Named hyperparameter presets (the only place they live); imports nothing heavy, so the CLI can list them."""

from __future__ import annotations

from dataclasses import dataclass

ALGORITHMS = ("ppo", "impala", "appo")

ANGLE_FREQUENCIES = 8
"""Fourier frequencies of the angles the critic sees, and the policy unless its preset says otherwise
(`training/module.py` explains both)."""


@dataclass(frozen=True)
class Preset:
    """Hyperparameters of one named preset for one algorithm (RLlib's names)."""

    lr: float
    gamma: float
    entropy_coeff: float
    vf_loss_coeff: float
    grad_clip: float
    train_batch_size: int
    lambda_: float = 0.95
    """PPO: GAE's lambda; IMPALA and APPO: v-trace's (traces cut by lambda, `learners.vtrace_lambda`)."""
    pg_lambda: float | None = None
    """IMPALA/APPO: the share of the next state's v-trace correction in the policy-gradient advantage
    (`learners.vtrace_lambda`); None: 1, IMPALA's; at `lambda_` it is GAE's advantage, PPO's, on-policy."""
    lr_final: float | None = None
    """The learning rate at the end of the budget, reached linearly from `lr` (RLlib's schedule); None: constant."""
    lr_knee: float | None = None
    """With `lr_final`: the rate at `lr_knee_at` of the budget, a bend in the linear fall (three points); None: none."""
    lr_knee_at: float = 0.5
    """Where the bend `lr_knee` sits, as a share of the budget's env steps."""
    entropy_final: float | None = None
    """The entropy coefficient at the end of the budget, reached linearly from `entropy_coeff`; None: constant."""
    policy_angle_frequencies: int = ANGLE_FREQUENCIES
    """Fourier frequencies of the angles the policy net sees (the critic always sees ANGLE_FREQUENCIES)."""
    num_epochs: int = 1
    minibatch_size: int | None = None
    """IMPALA/APPO: a multiple of `rollout_fragment_length` (RLlib's rule); None: the whole batch."""
    clip_param: float | None = None
    """PPO and APPO: the surrogate's clip on the probability ratio; None: RLlib's (PPO 0.3, APPO 0.4)."""
    kl_coeff: float | None = None
    """PPO and APPO: the starting weight of the KL penalty between the ratio's reference and the trained policy,
    which RLlib adapts toward a KL of 0.01; 0: off; None: RLlib's (PPO on at 0.2, APPO off)."""
    target_update_freq: float | None = None
    """APPO: how often its target policy (the ratio's reference) is refreshed, in RLlib's unit (circular-buffer
    batches x passes x batch size of trained steps); None: RLlib's 2."""
    circular_buffer_batches: int | None = None
    """APPO: train batches its learner's circular buffer holds, each trained on at most `circular_buffer_passes`
    times (RLlib's `circular_buffer_num_batches` and `circular_buffer_iterations_per_batch`); None: RLlib's 8
    and 2. The learner draws from the buffer at random, so it holds how stale a trained batch can be."""
    circular_buffer_passes: int | None = None
    """APPO: how often each batch of the circular buffer may be trained on (above); None: RLlib's 2."""
    frozen_critic: int = 0
    """APPO: 1 computes v-trace's advantages and value targets with a copy of the critic taken at each refresh of
    the target policy (`learners.FrozenCritic`), as PPO computes its GAE once per batch; 0: RLlib's, with the
    critic being trained on the same minibatch."""
    learner_queue: int | None = None
    """APPO: a plain queue of this many train batches in place of the circular buffer, each batch trained once
    (`num_epochs` passes) and sampling held back while it is full, so the runners wait for the learner as
    PPO's do (RLlib's `use_circular_buffer` False, `simple_queue_size`); None: the circular buffer."""
    rollout_fragment_length: int | str = "auto"
    min_time_s_per_iteration: float = 0.0
    env_runners: int = 2
    """Remote env runners (0: sample in the trial process). A layout, not a hyperparameter: every algorithm samples
    on 2 runners by default, as users run it on a laptop and a cluster; `--env-runners` overrides it (0 saves the
    transfers on 2 cores, a cluster wants more)."""


LAYOUT = ("rollout_fragment_length", "min_time_s_per_iteration", "env_runners")
"""Preset fields that shape how a run executes rather than what it learns (not tunable by sweeps)."""


_A3C_PAPER = Preset(  # Table 1, A3C column (served by IMPALA/APPO)
    lr=7e-4, gamma=0.99, entropy_coeff=0.01, vf_loss_coeff=0.5, grad_clip=0.5, train_batch_size=32, lambda_=1.0,
    rollout_fragment_length=32, min_time_s_per_iteration=2.0,
)  # fmt: skip
_ASYNC_FAST = Preset(
    lr=1e-3, lr_final=5e-5, gamma=0.995, entropy_coeff=0.01, vf_loss_coeff=0.5, grad_clip=40.0, lambda_=1.0,
    train_batch_size=500, num_epochs=2, minibatch_size=250, rollout_fragment_length=50, min_time_s_per_iteration=0.4,
)  # fmt: skip
"""IMPALA/APPO, fast: the learner trains on batches of 500 env steps (50-step fragments of the 32 envs), two passes in
minibatches of 250: 8 updates per 1,000 env steps (APPO about 9: its circular buffer's replay trains 2.2 samples per
env step, measured); with one pass over whole batches it made 0.6, and after 150,000 env steps its
policy was still uniform (entropy 3.29 of 3.30). Discount, learning rate, its fall to 5e-5 and entropy as PPO's:
at a constant 1e-3 and entropy 0.003 IMPALA settled 13 % of the 20 starts within 1 % on map-1 (median gap 3.25,
seeds 0-2); with the rate falling, 40, 40 and 25 % (gaps 1.30, 2.99, 2.96); with entropy 0.01 too, 35, 55 and
60 % (gaps 1.44, 0.60, 0.86). It keeps the angle frequencies in its policy (without them: 0 %).
Iterations of at least 0.4 s (about 4,000 env steps on 2 cores): the protocol, every 5 iterations, then evaluates
about every 20,000 steps, some 30 times in the async budget as in PPO's, and the run ends on the best of as many
policies; at 2 s it evaluated every 50,000 (8 times) and APPO settled 6 of 10 runs (map-1, map-2, seeds 0-4) at
90 % of the starts within 1 %, at 0.4 s 18 of 24 when adopted (seeds 0-8; docs/decisions.md has every tally since)."""
PRESETS: dict[str, dict[str, Preset]] = {
    "fast": {
        # 2,000 steps an iteration, 4 epochs of 4 minibatches: about 0.25 s of learner time on 2 cores
        # (8 updates per 1,000 steps; the first preset's 32 cost 4x the learner time for no better curves).
        # GAE lambda 0.5: the advantage leans on the critic rather than on 20 steps of random future moves,
        # whose noise drowned the one step's effect (lambda 0.95: no start settled within 1 % in 150k steps).
        # gamma 0.995: at 0.99 even the exact optimal policy (value iteration, `search/ideal.py`) stops at a
        # nearer, lesser shape from 3 of the 20 protocol starts on map-1, and PPO's settled median gap stayed
        # near 3.3 for 600,000 steps; at 0.995 the optimal policy reaches the 1 % band from all 20 and
        # PPO's gap at 150,000 steps was 1.6-3.0 over 3 seeds.
        # lr falls linearly to 5e-5 over the budget: once the policy flows to the best region, full-size updates
        # kept moving where its flows end (share of the 20 starts within 1 % jumping 0.6-1.0 between
        # evaluations); decayed, the last policy (map-1 seeds 0 and 4, map-2 seeds 0 and 1) settled 15, 16, 20
        # and 14 of 20 starts within 1 %, against 20, 12, 14 and 0 at a constant 1e-3.
        # entropy 0.01: at 0.003 a smooth policy could commit to the wrong region early (main job, seed 4: every
        # start 1.74 R1 under the optimum; seed 1: 12 of 20 within 1 %); at 0.01 seeds 0-4 settled 20 of 20.
        "ppo": Preset(
            lr=1e-3,
            lr_final=5e-5,
            policy_angle_frequencies=0,  # a policy smooth in the angles: one flow to the best region (module.py)
            gamma=0.995,
            entropy_coeff=0.01,
            vf_loss_coeff=0.5,
            grad_clip=10.0,
            train_batch_size=2000,
            lambda_=0.5,
            num_epochs=4,
            minibatch_size=500,
        ),
        "impala": _ASYNC_FAST,
        "appo": _ASYNC_FAST,
    },
    "paper": {
        # Table 1, PPO column: batch 4096, 15 epochs, 5 optimisation steps (minibatches) an epoch.
        "ppo": Preset(
            lr=3e-4,
            gamma=0.99,
            entropy_coeff=0.01,
            vf_loss_coeff=0.5,
            grad_clip=0.5,
            train_batch_size=4096,
            num_epochs=15,
            minibatch_size=4096 // 5,
        ),
        "impala": _A3C_PAPER,
        "appo": _A3C_PAPER,
    },
}
DEFAULT_TIMESTEPS = 300_000
"""The main job's budget: 1-2 min of training on 2 cores (2,800-6,400 env steps/s end to end, by machine). At 200,000
steps PPO settled 100 % of the 20 starts within 1 % on map-1 for seeds 0-2 and 100-102 on an AMD EPYC (map-2: 90 % for
seed 1, 100 % for the others), but on
an Intel Xeon with AVX-512 (a seed's path turns on the CPU's float arithmetic) 5, 45, 0, 100, 100, 55 % on map-1 for
seeds 200-205 (100 % on map-2); at 300,000 100, 100, 100, 90, 90, 75 % and 100 % on map-2 for all six
(docs/decisions.md). The learning rate falls to its floor over the budget, so a longer budget also explores longer."""
TRANSFER_TIMESTEPS = 200_000
"""A transfer run's budget (`transfer`, `bench_transfer.py`): Table 5's 36 runs (6 maps x 3 seeds x 2 modes) took 44
minutes at 200,000 steps on 2 cores, within issue 32's hour; at the main job's 300,000 they would take about 67."""
ENVS_PER_RUNNER = 16
"""Sub-envs each env runner steps together (one forward pass serves them all): on the default 2 runners, the 32
envs in all the presets were tuned on, each fragment 62 steps of each env. With 2 x 32 (fragments of 31 steps) the
main job settled 14, 20, 20 of 20 starts within 1 % on map-1 and 17, 20, 20 on map-2 (seeds 0-2); with 2 x 16,
20, 20, 20 and 20, 18, 20 (docs/decisions.md). `--env-runners 0 --envs-per-runner 32` is the same 32 envs
in the trial process."""
