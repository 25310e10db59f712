"""Whether a run's recorded configuration (its config.json) is the one a job would run now: setting by setting,
so a resume reads back only runs that measure the same thing, and names the first setting that differs. No Ray.
"""

from __future__ import annotations

import json
from dataclasses import fields
from typing import Any

from smorphi_rl.config_fields import field_default
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.presets import Preset

IGNORED = ("name", "address", "map_digests")
"""Written beside the settings but not settings: the run's folder name, the cluster it ran on and its maps' digests
(which a resume checks apart: `resume.continue_train_run`)."""


def setting_differs(stored: dict[str, Any], wanted_config: dict[str, Any]) -> str | None:
    """The first setting (`key: stored, this job: value`) in which a run's config.json differs from
    `wanted_config` (`TrainConfig.to_dict`); None when none does. A setting the run's version did not have yet
    counts as the same when the new configuration holds its default (the value that keeps the older behaviour)."""
    wanted = flatten(json.loads(json.dumps(wanted_config)))
    old = flatten({k: v for k, v in stored.items() if k not in IGNORED})
    defaults = field_defaults()
    for key in sorted(set(old) | set(wanted)):
        if key not in old and key in defaults and wanted.get(key) == defaults[key]:
            continue
        if old.get(key, "(none)") != wanted.get(key, "(none)"):
            return f"{key}: {old.get(key, '(none)')!r}, this job: {wanted.get(key, '(none)')!r}"
    return None


def field_defaults() -> dict[str, Any]:
    """Every TrainConfig setting's default as config.json writes it (dotted keys: `env.w1`,
    `hyperparameters.pg_lambda`)."""
    out: dict[str, Any] = {}
    for prefix, cls in (("", TrainConfig), ("env.", EnvConfig), ("hyperparameters.", Preset)):
        for f in fields(cls):
            try:
                out[prefix + f.name] = json.loads(json.dumps(field_default(cls, f.name)))
            except (KeyError, TypeError):
                continue  # no default, or a nested settings object (its own fields are listed under its prefix)
    return out


def flatten(doc: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested JSON object as one level of dotted keys (`{"env": {"w1": 1}}` -> `{"env.w1": 1}`)."""
    out: dict[str, Any] = {}
    for key, value in doc.items():
        if isinstance(value, dict) and value:
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out
