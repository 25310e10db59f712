"""Fine-tuning's weights: the pretrained critic predicts the same values under the new run's normalisation."""

from pathlib import Path

import numpy as np
import torch

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.training.checkpoints import build_module
from smorphi_rl.training.finetune import critic_renormalised


def test_the_pretrained_critic_predicts_the_same_values_under_a_new_normalisation():
    env = MorphologyEnv({"maps": [str(Path(__file__).resolve().parents[2] / "maps" / "val-1.yaml")]})
    trained_with = {"value_offset": 45.6, "value_scale": 634.6}
    now = {"value_offset": 13.3, "value_scale": 224.9}
    pretrained = build_module(env.observation_space, env.action_space, trained_with)
    with torch.no_grad():
        for p in pretrained._vf.head.parameters():  # a trained head, not the init's near-zero one
            p.normal_(0.0, 0.05)
    fresh = build_module(env.observation_space, env.action_space, now)
    state = {k: v.detach().numpy().copy() for k, v in pretrained.state_dict().items()}
    fresh.load_state_dict({k: torch.as_tensor(v) for k, v in critic_renormalised(state, trained_with, now).items()})
    obs = [env.reset(seed=s)[0] for s in range(8)]
    batch = {"obs": {k: torch.as_tensor(np.stack([o[k] for o in obs])) for k in obs[0]}}
    with torch.no_grad():
        before, after = pretrained.compute_values(batch), fresh.compute_values(batch)
        unscaled = build_module(env.observation_space, env.action_space, now)
        unscaled.load_state_dict(pretrained.state_dict())
        plain = unscaled.compute_values(batch)
    assert torch.allclose(before, after, rtol=1e-4, atol=1e-3)
    assert not torch.allclose(before, plain, rtol=1e-2)  # loaded as it was, the critic would predict other values
