"""The adapter's private names still exist with the shape it relies on, and each of its overrides takes effect:
these fail first when Ray, RLlib, Tune, tensorboardX, torch or numpy change underneath."""

from __future__ import annotations

import inspect
import io
import subprocess

import pytest
import torch

from smorphi_rl import rllib_compat
from smorphi_rl.rllib_compat import LibraryChanged, with_globals


def _library_function(x):
    return len(x)


def test_with_globals_resolves_the_names_to_ours_and_leaves_the_original_alone():
    copy = with_globals(_library_function, len=lambda x: -1)
    assert copy([1, 2]) == -1
    assert _library_function([1, 2]) == 2 and globals().get("len") is None  # nothing assigned anywhere
    with pytest.raises(LibraryChanged, match="no longer calls sorted"):
        with_globals(_library_function, sorted=sorted)


def test_a_private_name_gone_is_one_line_naming_it():
    from smorphi_rl.errors import SmorphiError

    assert issubclass(LibraryChanged, SmorphiError)  # the CLI prints it in one line
    with pytest.raises(LibraryChanged, match="has no _learner_connector any more"):
        rllib_compat.learner_pipeline(object())


def test_the_runners_private_loop_is_what_the_adapter_takes_it_for():
    from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

    loop = SingleAgentEnvRunner._sample
    assert "unbatch" in loop.__code__.co_names and "_make_on_episode_callback" in loop.__code__.co_names
    assert list(inspect.signature(loop).parameters) == [
        "self", "num_timesteps", "num_episodes", "explore", "random_actions", "force_reset",
    ]  # fmt: skip
    callback = SingleAgentEnvRunner._make_on_episode_callback
    assert list(inspect.signature(callback).parameters) == ["self", "which", "idx", "episodes"]


def _runner(unbatch, **callbacks):
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training.callbacks import MorphologyCallbacks
    from smorphi_rl.training.config import TrainConfig, algorithm_config, register_env

    register_env()
    cfg = TrainConfig(env=EnvConfig.from_dict({"max_steps": 20}), seed=3, envs_per_runner=4)
    config = algorithm_config(cfg, MorphologyCallbacks).callbacks(**callbacks)
    return rllib_compat.runner_mixin(unbatch)(config=config)


def test_the_runner_splits_each_step_with_ours_and_skips_step_callbacks_only_when_none_is_set():
    from ray.rllib.utils.spaces.space_utils import unbatch

    calls = []

    def counting(batched):
        calls.append(1)
        return unbatch(batched)

    steps: list[int] = []
    for on_step in (None, lambda **kwargs: steps.append(1)):
        runner = _runner(counting, **({"on_episode_step": on_step} if on_step else {}))
        assert isinstance(runner._callbacks, list)  # what the skip reads
        calls.clear()
        runner.sample(num_timesteps=4 * 40)
        runner.stop()
        assert len(calls) >= 2 * 40  # observations and actions, every step
        assert (len(steps) > 4 * 30) == (on_step is not None)  # made for every env and step, or not at all


def test_the_runners_methods_work_when_shipped_by_value_as_ray_ships_them_to_remote_runners():
    import cloudpickle

    from smorphi_rl.training.sampling import LeanEnvRunner, split_by_env

    created: list[int] = []
    runner = _runner(split_by_env, on_episode_created=lambda **kwargs: created.append(1))
    shipped = {name: cloudpickle.loads(cloudpickle.dumps(getattr(LeanEnvRunner, name)))
               for name in ("_sample", "_make_on_episode_callback")}  # fmt: skip
    try:
        episodes = shipped["_sample"](runner, num_timesteps=40, explore=True)
        before = len(created)
        shipped["_make_on_episode_callback"](runner, "on_episode_created", 0, episodes)
    finally:
        runner.stop()
    assert sum(len(e) for e in episodes) >= 40 and before >= 4  # every step sampled, an episode made on each env
    assert len(created) == before + 1  # the shipped method calls the user's callback


def test_the_learner_internals_the_adapter_reaches_are_there():
    from ray.rllib.algorithms.impala import impala_learner
    from ray.rllib.core.learner.learner import Learner

    thread_init = inspect.signature(impala_learner._LearnerThread.__init__).parameters
    assert "update_method" in thread_init
    assert "_update_method" in inspect.getsource(impala_learner._LearnerThread)
    assert "self._learner_thread" in inspect.getsource(impala_learner.IMPALALearner.build)
    assert "self._learner_connector = self.config.build_learner_connector(" in inspect.getsource(Learner.build)


def test_the_learner_state_queue_the_adapter_reads_is_there():
    from ray.rllib.algorithms.impala import impala, impala_learner

    from smorphi_rl import rllib_compat

    thread, update = inspect.getsource(impala_learner._LearnerThread), inspect.getsource(impala_learner.IMPALALearner)
    assert "self.learner._learner_state_queue.put_nowait(learner_state)" in thread
    assert "self._learner_state_queue = Queue(maxsize=1)" in update
    assert "self._learner_state_lock = threading.Lock()" in update
    assert "self._learner_state = self._learner_state_queue.get_nowait()" in update
    assert f'"{rllib_compat.LEARNER_STATE_KEY}"' in inspect.getsource(impala.IMPALA.training_step)


def test_the_normalised_losses_are_rllibs_own_with_the_normalising_vtrace():
    from ray.rllib.algorithms.appo.torch.appo_torch_learner import APPOTorchLearner
    from ray.rllib.algorithms.impala.torch.impala_torch_learner import IMPALATorchLearner

    from smorphi_rl.training.learners import NormalisedAPPOLearner, NormalisedIMPALALearner, normalised_vtrace

    for ours, theirs in ((NormalisedIMPALALearner, IMPALATorchLearner), (NormalisedAPPOLearner, APPOTorchLearner)):
        loss = ours.compute_loss_for_module.__wrapped__  # inside the wrap that sets v-trace's lambda
        assert loss.__code__ is theirs.compute_loss_for_module.__code__  # RLlib's loss, op for op
        assert loss.__globals__["vtrace_torch"] is normalised_vtrace
        assert theirs.compute_loss_for_module.__globals__["vtrace_torch"] is not normalised_vtrace  # RLlib's intact


def test_the_time_major_layout_is_the_one_rllibs_vtrace_losses_use():
    """Our mask and frozen values go through RLlib's own helper, which its IMPALA and APPO losses call by keyword."""
    from ray.rllib.algorithms.appo.torch.appo_torch_learner import APPOTorchLearner
    from ray.rllib.algorithms.impala.torch import vtrace_torch_v2
    from ray.rllib.algorithms.impala.torch.impala_torch_learner import IMPALATorchLearner

    for learner in (IMPALATorchLearner, APPOTorchLearner):
        assert "make_time_major" in learner.compute_loss_for_module.__code__.co_names
    keywords = inspect.signature(vtrace_torch_v2.make_time_major).parameters
    assert keywords["trajectory_len"].kind is keywords["recurrent_seq_len"].kind is inspect.Parameter.KEYWORD_ONLY
    assert rllib_compat.time_major(torch.arange(6.0), 3).tolist() == [[0.0, 3.0], [1.0, 4.0], [2.0, 5.0]]


def test_torchs_fused_norms_scaling_and_version_counter():
    tensors = [torch.tensor([3.0, 4.0]), torch.tensor([1.0])]
    assert torch.equal(rllib_compat.tensor_norms(tensors), torch.tensor([5.0, 1.0]))
    before = rllib_compat.tensor_version(tensors[0])
    rllib_compat.scale_each_(tensors, torch.tensor([2.0, 0.5]))
    assert torch.equal(tensors[0], torch.tensor([6.0, 8.0])) and torch.equal(tensors[1], torch.tensor([0.5]))
    assert rllib_compat.tensor_version(tensors[0]) > before  # an in-place step bumps it


def test_rays_console_popen_is_swapped_only_inside_the_block_and_detaches():
    from ray._private import services

    original = services.ConsolePopen
    assert issubclass(original, subprocess.Popen)
    assert "ConsolePopen" in inspect.getsource(services.start_ray_process)
    with rllib_compat.daemons_in_their_own_session():
        child = services.ConsolePopen(["sleep", "0"])
        child.wait()
        assert child.args == ["sleep", "0"]
        assert services.ConsolePopen is not original
    assert services.ConsolePopen is original


def test_tunes_tensorboard_writers_are_where_the_adapter_reads_them(tmp_path):
    from ray.tune.logger.tensorboardx import TBXLoggerCallback

    class Trial:
        local_path = str(tmp_path)

        def init_local_path(self):
            pass

    callback, trial = TBXLoggerCallback(), Trial()
    writer = rllib_compat.tune_trial_writer(callback, trial)
    assert rllib_compat.tune_trial_writer(callback, trial) is writer  # opened once
    assert rllib_compat.tune_last_scalars(callback, trial) == {}
    assert hasattr(rllib_compat.summary_file_writer(writer), "add_summary")
    writer.close()


def test_numpys_unpickling_helpers_are_the_ones_its_pickles_name():
    import pickle
    import pickletools

    import numpy as np

    helpers = rllib_compat.numpy_unpickle_helpers()
    data = pickle.dumps((np.arange(3), np.random.default_rng(0), np.random.SeedSequence(1)), protocol=2)
    named = set()
    for op, arg, _ in pickletools.genops(data):
        if op.name == "GLOBAL":
            module, name = arg.split(" ")
            named.add((module, name))
    private = {pair for pair in named if pair[1].startswith("_")}
    assert private and private <= set(helpers)


def test_the_python_unpickler_dispatches_build_to_a_method_a_subclass_can_check():
    import pickle

    unpickler = rllib_compat.python_unpickler()
    assert unpickler.dispatch[pickle.BUILD[0]] is unpickler.load_build and callable(unpickler.find_class)
    for op, method in ((pickle.SETITEM, "load_setitem"), (pickle.SETITEMS, "load_setitems"), (pickle.DICT, "load_dict"),
                       (pickle.ADDITEMS, "load_additems"), (pickle.FROZENSET, "load_frozenset")):  # fmt: skip
        assert unpickler.dispatch[op[0]] is getattr(unpickler, method), method
    seen = []  # the items since the last MARK are the stack itself: what the key checks read

    class Peek(unpickler):  # type: ignore[misc, valid-type]
        def load_setitems(self) -> None:
            seen.append(list(self.stack))
            super().load_setitems()

        dispatch = {**unpickler.dispatch, pickle.SETITEMS[0]: load_setitems}  # noqa: RUF012

    assert Peek(io.BytesIO(pickle.dumps({"a": 1, "b": 2}, protocol=4))).load() == {"a": 1, "b": 2}
    assert seen == [["a", 1, "b", 2]]


def test_a_job_submitted_with_a_working_dir_is_told_from_one_without(monkeypatch):
    """`ray job submit --working-dir` hands its driver the job's config in the variable Ray names; a second
    working_dir in `ray.init` then fails ("Failed to merge the Job's runtime env"), so `ray_session` adds none."""
    import json

    from ray._private.worker import RAY_JOB_CONFIG_JSON_ENV_VAR  # where Ray's init reads it

    from smorphi_rl import cluster

    monkeypatch.delenv(RAY_JOB_CONFIG_JSON_ENV_VAR, raising=False)
    assert not rllib_compat.submitted_with_working_dir()
    assert cluster._empty_working_dir() is not None
    for config, submitted in (({"runtime_env": {"working_dir": "gcs://_ray_pkg_1.zip"}}, True),
                              ({"runtime_env": {"pip": ["x"]}}, False), ("not json{", False)):  # fmt: skip
        monkeypatch.setenv(RAY_JOB_CONFIG_JSON_ENV_VAR, config if isinstance(config, str) else json.dumps(config))
        assert rllib_compat.submitted_with_working_dir() is submitted
        assert (cluster._empty_working_dir() is None) is submitted
