"""The stacked PPO update on a CUDA device equals the CPU update (runs where a GPU is present)."""

import pytest
import torch

from lhf_hf.collection.batched_ppo import Rollout, StackedPolicy, make_optimizer
from lhf_hf.collection.ppo_backends import ppo_update

from .rollouts import random_rollout

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@cuda
@pytest.mark.parametrize("gradients", ["manual", "autograd"])
def test_ppo_update_on_cuda_equals_cpu(gradients):
    torch.backends.cuda.matmul.allow_tf32 = False  # exact fp32 products, as on the CPU
    L, N, b = 3, 40, 10
    data = random_rollout(L, N)
    g = torch.Generator().manual_seed(0)
    perms = [torch.argsort(torch.rand(L, N, generator=g), dim=1) for _ in range(2)]
    results = []
    for device in ("cpu", "cuda"):
        policy = StackedPolicy(L, 2, 5, torch.Generator().manual_seed(1)).to(device)
        opt = make_optimizer(policy, 3e-4)
        moved = Rollout(*(getattr(data, f).to(device) for f in data.__dataclass_fields__))
        ppo_update(
            policy,
            opt,
            moved,
            2,
            b,
            permutations=[p.to(device) for p in perms],
            gradients=gradients,
        )
        results.append([p.detach().cpu() for p in policy.parameters()])
    for cpu, gpu in zip(*results, strict=True):
        torch.testing.assert_close(gpu, cpu, atol=1e-5, rtol=1e-4)


@cuda
def test_batched_collector_learns_on_cuda():
    """A chunk collected with the learners on the GPU: valid histories that improve, like the CPU's
    (the statistical CPU-vs-SB3 equivalence lives in test_equivalence.py)."""
    import numpy as np

    from lhf_hf.collection.batched_collector import collect_chunk
    from lhf_hf.configs import CollectConfig

    cfg = CollectConfig(
        "darkroom", tasks="3,40", histories=10, steps=1000, collector="batched", device="cuda"
    )
    out = collect_chunk(cfg, cfg.tasks, 0)
    assert [h.task for h in out] == [3, 40]
    for h in out:
        h.validate(cfg.horizon)
        assert h.obs.shape == (10, 1000, 2) and h.actions.shape == (10, 1000)
        assert set(np.unique(h.actions)) <= set(range(5))
        returns = h.rewards.reshape(10, -1, 20).sum(-1)  # (histories, episodes)
        assert (
            returns[:, -10:].mean() > returns[:, :10].mean() + 5.0
        )  # CPU: 1.9 -> 13.9, 2.9 -> 19.7
