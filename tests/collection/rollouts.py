"""A random PPO rollout for the stacked-update tests (speed and gradients do not depend on the data)."""

import torch

from lhf_hf.collection.batched_ppo import Rollout


def random_rollout(L: int, N: int, seed: int = 0) -> Rollout:
    """(L learners, N samples) of grid observations, actions, advantages and returns."""
    g = torch.Generator().manual_seed(seed)
    return Rollout(
        obs=torch.randint(0, 9, (L, N, 2), generator=g).float(),
        actions=torch.randint(0, 5, (L, N), generator=g),
        # old log-probs near the policy's (~log 1/5) so that ratios land on both sides of the clip
        old_logp=torch.log(torch.full((L, N), 0.2)) + 0.3 * torch.randn(L, N, generator=g),
        old_values=torch.randn(L, N, generator=g),
        advantages=torch.randn(L, N, generator=g),
        returns=torch.randn(L, N, generator=g),
    )
