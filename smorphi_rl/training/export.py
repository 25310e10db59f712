"""A trained policy out of its RLlib checkpoint into the plain policy files of `policy_file.py`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from smorphi_rl.designer import TRAINED_SIDES_KEY, sides_trained_on
from smorphi_rl.policy_file import write_policy
from smorphi_rl.training.checkpoints import TARGET_PREFIX, load_module


def export_policy(checkpoint: Path, out_dir: Path, about: dict[str, Any], module: Any = None) -> Path:
    """Write the policy and value nets of `checkpoint` (read safely) to `out_dir` with `about` (where it came from,
    its figures) beside them, and the sides of the floors it was trained on (`designer.sides_trained_on`); APPO's
    target net is left out (fine-tuning rebuilds it from the policy)."""
    module = module if module is not None else load_module(checkpoint)
    sides = sides_trained_on(_maps_of(module.model_config.get("env_config")))
    trained = about.get("trained")
    pretrained = trained.get("pretrained") if isinstance(trained, dict) else None
    if sides is not None and isinstance(pretrained, str):  # a fine-tune knows the floors its start was trained on too
        before = pretrained_sides(Path(pretrained))
        sides = None if before is None else (min(sides[0], before[0]), max(sides[1], before[1]))
    about = about if sides is None else {TRAINED_SIDES_KEY: list(sides), **about}
    weights = {k: v.detach().numpy() for k, v in module.state_dict().items() if not k.startswith(TARGET_PREFIX)}
    observation = {k: tuple(int(d) for d in space.shape) for k, space in module.observation_space.spaces.items()}
    nvec = [int(n) for n in module.action_space.nvec]
    return write_policy(out_dir, weights, observation, nvec, dict(module.model_config), about)


def run_record(checkpoint: Path) -> dict[str, Any] | None:
    """What the run that wrote `checkpoint` recorded of it, when its summary.json (a run's, or a sweep trial's)
    names this very checkpoint as the policy the run ended on: the env steps that policy trained for (the run's too,
    where it ended on an earlier one), the training time and the policy it was fine-tuned from; None otherwise."""
    from smorphi_rl.errors import SmorphiError
    from smorphi_rl.inputs import is_finite_number, read_json_object

    for folder in (checkpoint.parent, checkpoint.parent.parent):  # a trial's folder, a run's folder
        if not (folder / "summary.json").is_file():
            continue
        try:
            summary = read_json_object(folder / "summary.json", "run summary")
            named = summary.get("checkpoint")
            same = isinstance(named, str) and Path(named).resolve() == checkpoint.resolve()
        except (SmorphiError, OSError, ValueError):
            continue
        steps, wall = summary.get("env_steps"), summary.get("wall_s")
        if same and type(steps) is int and steps >= 0:
            evaluation = summary.get("evaluation")
            kept = evaluation.get("policy_env_steps") if isinstance(evaluation, dict) else None
            record: dict[str, Any] = {"env_steps": kept if type(kept) is int and 0 <= kept <= steps else steps}
            if record["env_steps"] != steps:  # the run ended on an earlier policy it evaluated better
                record["run_env_steps"] = steps
            if isinstance(wall, int | float) and is_finite_number(wall) and wall >= 0:
                record["wall_s"] = round(wall)
            if isinstance(summary.get("pretrained"), str):
                record["pretrained"] = summary["pretrained"]
            return record
    return None


def pretrained_sides(path: Path) -> tuple[float, float] | None:
    """The sides of the floors the policy a run was fine-tuned from was trained on: an exported policy's record, or
    a checkpoint's maps; None where that policy is gone or says nothing."""
    from smorphi_rl.errors import SmorphiError
    from smorphi_rl.policy_file import is_policy_dir

    try:
        if is_policy_dir(path):
            from smorphi_rl.designer import load_designer

            return load_designer(path).trained_sides
        from smorphi_rl.training.checkpoints import find_checkpoint

        module = load_module(find_checkpoint(str(path)))
        return sides_trained_on(_maps_of(module.model_config.get("env_config")))
    except (SmorphiError, OSError):
        return None


def _maps_of(env_config: Any) -> tuple[str, ...]:
    """The map entries a policy was trained on, as its env configuration normalises them; none where it is not one."""
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.errors import SmorphiError

    try:
        return EnvConfig.recorded(dict(env_config)).maps if isinstance(env_config, dict) else ()
    except SmorphiError:
        return ()
