"""``ppo_update``: one batched PPO update by the implementation asked for.

Three implementations of the same update, all tested against SB3's ``PPO.train``:

- ``"autograd"``: ``batched_ppo.ppo_update_autograd``, the plain PyTorch reference;
- ``"manual"``: ``ppo_manual.ppo_update_manual``, the loss gradient written by hand; any device;
- ``"kernel"``: ``ppo_kernel.ppo_update_kernel``, the C++ kernel; CPU, float32, Adam;
- ``"auto"`` (default): the kernel where it applies and builds, else ``"manual"`` (logged once).
"""

from __future__ import annotations

import logging

import torch

from lhf_hf.errors import UserError

from . import native
from .batched_ppo import Rollout, StackedPolicy, ppo_update_autograd
from .ppo_kernel import kernel_unsupported, ppo_update_kernel
from .ppo_manual import ppo_update_manual

logger = logging.getLogger(__name__)

GRADIENTS = ("auto", "kernel", "manual", "autograd")


def ppo_update(
    policy: StackedPolicy,
    optimizer: torch.optim.Optimizer,
    data: Rollout,
    n_epochs: int,
    batch_size: int,
    permutations: list[torch.Tensor] | None = None,
    generator: torch.Generator | None = None,
    gradients: str = "auto",
) -> None:
    """SB3 ``PPO.train`` for every learner at once, by ``gradients`` (see the module docstring).

    ``permutations``: one (L, N) index tensor per epoch (tests pass SB3's); by default drawn from
    ``generator``.  Runs on the device of ``policy`` and ``data``.
    """
    if gradients not in GRADIENTS:
        raise UserError(f"gradients must be one of {GRADIENTS}, got {gradients!r}")
    args = (policy, optimizer, data, n_epochs, batch_size, permutations, generator)
    if gradients == "autograd":
        return ppo_update_autograd(*args)
    if gradients in ("auto", "kernel"):
        reason = kernel_unsupported(policy, optimizer, data)
        if reason is None:
            try:
                native.load(policy.net.weights[0].shape[-1])
            except native.KernelUnavailable as e:
                reason = str(e)
        if reason is None:
            return ppo_update_kernel(*args)
        if gradients == "kernel":
            raise native.KernelUnavailable(reason)
        _warn_fallback(reason)
    return ppo_update_manual(*args)


_warned: set[str] = set()


def _warn_fallback(reason: str) -> None:
    if reason not in _warned:
        _warned.add(reason)
        logger.warning("batched PPO: the C++ kernel is not used (%s); torch ops instead", reason)
