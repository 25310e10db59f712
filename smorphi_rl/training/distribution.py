"""The policy's action distribution: RLlib's MultiCategorical, computed on all hinges at once when they are
of equal size (ours: three hinges of three moves).

RLlib's `TorchMultiCategorical` builds one torch Categorical per hinge and takes log-probabilities, entropies
and KL divergences hinge by hinge, then stacks and sums them: about 9 % of PPO's learner time here went to
these small calls and their backward passes. `HingeCategorical` does the same arithmetic, element for element,
on the logits viewed as (..., hinges, size), so every figure (and gradient) is the one RLlib's computes
(a test checks them bit for bit); sampling and anything else goes through RLlib's per-hinge categoricals,
built with it (one distribution a minibatch in the learner; the env runners sample without one).
"""

from __future__ import annotations

from typing import Any

import torch
from ray.rllib.core.distribution.torch.torch_distribution import TorchCategorical, TorchMultiCategorical


class HingeCategorical(TorchMultiCategorical):  # type: ignore[misc]  # RLlib's classes are untyped
    """`TorchMultiCategorical` whose log-probabilities, entropy and KL run on all hinges at once."""

    def __init__(self, categoricals: list[TorchCategorical] | None = None, *, logits: torch.Tensor | None = None,
                 input_lens: list[int] | None = None) -> None:  # fmt: skip
        self._normalised: torch.Tensor | None = None
        self._probs: torch.Tensor | None = None
        if logits is not None and input_lens is not None:
            size = input_lens[0]
            hinges = logits.reshape(*logits.shape[:-1], len(input_lens), size)
            self._normalised = hinges - hinges.logsumexp(dim=-1, keepdim=True)  # as torch's Categorical does
            categoricals = [TorchCategorical(logits=part) for part in torch.split(logits, input_lens, dim=-1)]
        super().__init__(categoricals=categoricals or [])

    @classmethod
    def from_logits(  # type: ignore[override]
        cls, logits: torch.Tensor, input_lens: list[int], temperatures: list[float] | None = None, **kwargs: Any
    ) -> TorchMultiCategorical:
        if len(set(input_lens)) != 1 or sum(input_lens) != logits.shape[-1]:
            return super().from_logits(logits, input_lens, temperatures or [], **kwargs)
        return cls(logits=logits, input_lens=input_lens)

    def _hinge_probs(self) -> torch.Tensor:
        """Each hinge's probabilities (torch's Categorical: the softmax of its normalised logits), kept."""
        if self._probs is None:
            self._probs = torch.softmax(self._normalised, dim=-1)  # type: ignore[arg-type]
        return self._probs

    def logp(self, value: Any, **kwargs: Any) -> Any:
        if self._normalised is None:
            return super().logp(value, **kwargs)
        per_hinge = self._normalised.gather(-1, value.long().unsqueeze(-1)).squeeze(-1)
        return torch.sum(per_hinge.movedim(-1, 0), dim=0)  # RLlib stacks the hinges first, then sums dim 0

    def entropy(self, **kwargs: Any) -> Any:
        if self._normalised is None:
            return super().entropy(**kwargs)
        clamped = torch.clamp(self._normalised, min=torch.finfo(self._normalised.dtype).min)
        return torch.sum(-(clamped * self._hinge_probs()).sum(-1), dim=-1)

    def kl(self, other: Any, **kwargs: Any) -> Any:
        if self._normalised is None or not isinstance(other, HingeCategorical) or other._normalised is None:
            return super().kl(other, **kwargs)
        # torch's categorical-categorical KL, hinge by hinge, in its order (which sets the backward pass's order)
        t = self._hinge_probs() * (self._normalised - other._normalised)
        t[(other._hinge_probs() == 0).expand_as(t)] = torch.inf
        t[(self._hinge_probs() == 0).expand_as(t)] = 0
        return torch.sum(t.sum(-1), dim=-1)
