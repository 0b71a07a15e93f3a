"""The batched PPO update by the C++ kernel (``kernels/ppo_update.cpp`` through ``native.py``).

Each learner's whole update runs in cache, learners split across ``torch.get_num_threads()``
threads: CPU, float32, a single-group Adam.  Without given permutations the kernel draws each
learner's permutations itself from one seed taken from the generator, so its minibatches differ
from the torch paths' (same law; part of a dataset's identity, ``CollectConfig.ppo_backend``).
"""

from __future__ import annotations

import math

import torch

from lhf_hf.errors import UserError

from . import native
from .batched_ppo import CLIP_RANGE, MAX_GRAD_NORM, VF_COEF, Rollout, StackedPolicy


def kernel_unsupported(policy: StackedPolicy, optimizer, data: Rollout) -> str | None:
    """Why the C++ kernel cannot run this update (None when it can)."""
    w = policy.net.weights
    if any(p.device.type != "cpu" or p.dtype != torch.float32 for p in policy.parameters()):
        return "the kernel runs float32 CPU policies only"
    if data.obs.device.type != "cpu":
        return "the kernel needs the rollout on the CPU"
    hidden = w[0].shape[-1]
    if w[1].shape[-2:] != (hidden, hidden) or hidden % 16 != 0:
        return f"the kernel needs two equal hidden layers, a multiple of 16 wide (got {tuple(w[1].shape[-2:])})"
    if not isinstance(optimizer, torch.optim.Adam) or len(optimizer.param_groups) != 1:
        return "the kernel implements a single-group torch.optim.Adam"
    group = optimizer.param_groups[0]
    if group["amsgrad"] or group["weight_decay"] != 0 or group["maximize"]:
        return "the kernel implements Adam without amsgrad, weight decay or maximize"
    if isinstance(group["lr"], torch.Tensor):
        return "the kernel needs a float learning rate"
    if {id(p) for p in group["params"]} != {id(p) for p in policy.parameters()}:
        return "the optimizer must hold exactly the policy's parameters"
    return None


def ppo_update_kernel(
    policy: StackedPolicy,
    optimizer: torch.optim.Optimizer,
    data: Rollout,
    n_epochs: int,
    batch_size: int,
    permutations: list[torch.Tensor] | None,
    generator: torch.Generator | None,
) -> None:
    """SB3 ``PPO.train`` for every learner at once, in the C++ kernel (check
    ``kernel_unsupported`` first)."""
    L, N = data.actions.shape
    params = policy.stacked_params()
    group = optimizer.param_groups[0]
    for p in params:  # torch's Adam state layout, so optimizer.state_dict() stays valid
        st = optimizer.state[p]
        if not st:
            st["step"] = torch.tensor(0.0, dtype=torch.float32)
            st["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
            st["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
    states = [optimizer.state[p] for p in params]
    steps = {float(st["step"]) for st in states}
    if len(steps) != 1:
        raise RuntimeError(f"Adam step counts differ across the policy's parameters: {steps}")
    perms = None
    if permutations is not None:
        perms = torch.stack([torch.as_tensor(p, dtype=torch.int64) for p in permutations])
        if perms.shape != (n_epochs, L, N):
            raise UserError(
                f"permutations: expected {n_epochs} of shape ({L}, {N}), got {tuple(perms.shape)}"
            )
        perms = perms.contiguous()
    seed = int(torch.randint(0, 2**62, (1,), generator=generator))
    tensors = {
        "obs": data.obs.to(torch.float32).contiguous(),
        "actions": data.actions.to(torch.int64).contiguous(),
        "old_logp": data.old_logp.to(torch.float32).contiguous(),
        "advantages": data.advantages.to(torch.float32).contiguous(),
        "returns": data.returns.to(torch.float32).contiguous(),
    }
    with torch.no_grad():
        native.ppo_update_kernel(
            tensors,
            [p.data for p in params],
            [st["exp_avg"] for st in states],
            [st["exp_avg_sq"] for st in states],
            n_epochs=n_epochs,
            batch_size=batch_size,
            perms=perms,
            seed=seed,
            lr=float(group["lr"]),
            betas=tuple(group["betas"]),
            eps=float(group["eps"]),
            step0=steps.pop(),
            clip_range=CLIP_RANGE,
            vf_coef=VF_COEF,
            max_grad_norm=MAX_GRAD_NORM,
        )
        n_steps = n_epochs * math.ceil(N / batch_size)
        for st in states:
            st["step"] += n_steps
