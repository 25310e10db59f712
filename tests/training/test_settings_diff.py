"""A run's config.json against the configuration a job would run now: setting by setting (no Ray)."""

from __future__ import annotations

import json
from dataclasses import replace

from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.settings_diff import setting_differs


def test_a_run_is_compared_setting_by_setting_and_a_setting_added_since_counts_at_its_default():
    cfg = TrainConfig(timesteps=2000)
    stored = json.loads(json.dumps(cfg.to_dict())) | {"name": "val-1-scratch-seed0", "address": None}
    assert setting_differs(stored, cfg.to_dict()) is None
    assert setting_differs(stored, replace(cfg, timesteps=4000).to_dict()) == "timesteps: 2000, this job: 4000"
    assert setting_differs(stored, cfg.with_env(w2=0.2).to_dict()) == "env.w2: 0.1, this job: 0.2"
    del stored["env"]["step_cost"]  # a run from before the setting existed
    assert setting_differs(stored, cfg.to_dict()) is None  # today's default keeps the older behaviour
    assert setting_differs(stored, cfg.with_env(step_cost=0.1).to_dict()) == "env.step_cost: '(none)', this job: 0.1"
