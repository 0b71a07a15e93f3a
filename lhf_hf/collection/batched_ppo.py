"""PPO for many learners at once: Stable-Baselines3's algorithm with stacked parameters.

L independent learners, each exactly SB3's ``PPO("MlpPolicy", ...)`` with its defaults:
separate 64-64 tanh actor and critic (``net_arch=dict(pi=[64, 64], vf=[64, 64])``), orthogonal
initialisation (gain sqrt(2) for hidden layers, 0.01 for the action head, 1 for the value head,
zero biases), Adam (eps 1e-5), GAE lambda 0.95, clip 0.2, value coefficient 0.5, entropy 0,
gradient-norm clip 0.5 per learner, per-minibatch advantage normalisation (unbiased std), value
bootstrap on time-limit truncation.  Learner l's weights are slice l of (L, in, out) tensors, so one
``baddbmm`` runs a layer of every learner; the summed loss gives each learner its own gradient and
Adam is elementwise, so a stacked update is L independent SB3 updates (``tests/collection`` checks
one update against SB3's own ``PPO.train``).

This file is the reference, to read top to bottom like a single-file PPO: ``StackedMLP`` ->
``StackedPolicy`` -> ``gae`` -> ``Rollout`` -> ``minibatches`` -> ``ppo_loss`` ->
``ppo_update_autograd``.  The same update, faster, sits beside it: ``ppo_manual.py`` (the loss
gradient written by hand) and ``ppo_kernel.py`` (the C++ kernel); ``ppo_backends.ppo_update``
chooses among the three.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch
from torch import nn

CLIP_RANGE = 0.2
GAE_LAMBDA = 0.95
VF_COEF = 0.5
MAX_GRAD_NORM = 0.5
ADAM_EPS = 1e-5  # SB3 sets eps=1e-5 for the policies' Adam
HIDDEN = (64, 64)  # SB3 MlpPolicy's net_arch for actor and critic


class StackedMLP(nn.Module):
    """L independent MLPs ``sizes[0] -> ... -> sizes[-1]``, tanh between layers, none at the end."""

    def __init__(
        self, num_learners: int, sizes: list[int], gains: list[float], generator: torch.Generator
    ) -> None:
        super().__init__()
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for fan_in, fan_out, gain in zip(sizes[:-1], sizes[1:], gains, strict=True):
            w = torch.empty(num_learners, fan_out, fan_in)  # (L, out, in) like nn.Linear.weight
            with one_thread():
                for l in range(num_learners):  # noqa: E741 - SB3: nn.init.orthogonal_(module.weight, gain)
                    w[l] = _orthogonal(fan_out, fan_in, gain, generator)
            self.weights.append(nn.Parameter(w.transpose(1, 2).contiguous()))  # (L, in, out)
            self.biases.append(nn.Parameter(torch.zeros(num_learners, 1, fan_out)))  # (L, 1, out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (L, B, in) -> (L, B, out)."""
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = torch.baddbmm(b, x, w)  # (L, B, out)
            if i < last:
                x = torch.tanh(x)
        return x


@contextmanager
def one_thread():
    """Torch (and its LAPACK) on one thread inside: LAPACK's QR of the same 64 x 64 Gaussian rounds
    differently with 1 and 2 threads, and PPO's learning amplifies a last-bit difference in the
    initial weights into other histories, so a dataset would depend on the machine's core count
    (measured: Darkroom, 4 tasks x 20 histories x 500 steps, summed rewards 13,380 at 1 thread vs
    13,398 at 2 before this).  A few thousand 64 x 64 QRs cost milliseconds on one thread."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _orthogonal(rows: int, cols: int, gain: float, generator: torch.Generator) -> torch.Tensor:
    """``torch.nn.init.orthogonal_`` with an explicit generator: QR of a Gaussian, sign-fixed."""
    flat = torch.randn(max(rows, cols), min(rows, cols), generator=generator)
    q, r = torch.linalg.qr(flat)
    q = q * torch.sign(torch.diagonal(r)).unsqueeze(0)
    if rows < cols:
        q = q.T
    return gain * q[:rows, :cols]


class StackedPolicy(nn.Module):
    """SB3 ``ActorCriticPolicy`` (MlpPolicy, discrete actions) for L learners.

    Actor and critic share nothing in SB3 (separate 64-64 nets), so they are stacked as one
    ``StackedMLP`` of 2L nets: rows [0, L) are the actors, rows [L, 2L) the critics.  One
    ``baddbmm`` per layer then runs both, halving the kernel launches of every step.  The critics'
    heads are padded from 1 to A outputs with zero weights that never receive a gradient (only
    column 0 is read), so Adam leaves them at zero.
    """

    def __init__(
        self,
        num_learners: int,
        obs_dim: int,
        num_actions: int,
        generator: torch.Generator,
        hidden: tuple[int, int] = HIDDEN,
    ) -> None:
        super().__init__()
        s2 = math.sqrt(2)
        L = num_learners
        # SB3 initialises mlp_extractor (gain sqrt 2), then action_net (0.01), then value_net (1).
        actor = StackedMLP(L, [obs_dim, *hidden, num_actions], [s2, s2, 0.01], generator)
        critic = StackedMLP(L, [obs_dim, *hidden, 1], [s2, s2, 1.0], generator)
        self.net = StackedMLP(2 * L, [obs_dim, *hidden, num_actions], [1.0, 1.0, 1.0], generator)
        with torch.no_grad():
            for i in range(3):
                self.net.weights[i].zero_()
                self.net.weights[i][:L] = actor.weights[i]
                self.net.weights[i][L:, :, : critic.weights[i].shape[-1]] = critic.weights[i]
                self.net.biases[i].zero_()
        self.num_learners = L

    def stacked_params(self) -> list[torch.Tensor]:
        """[W1, B1, W2, B2, W3, B3] of the 2L nets: the C++ kernel's parameter order."""
        return [t for i in range(3) for t in (self.net.weights[i], self.net.biases[i])]

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """obs (L, B, obs_dim) float -> (logits (L, B, A), values (L, B))."""
        L = self.num_learners
        out = self.net(torch.cat([obs, obs]))  # (2L, B, A)
        return out[:L], out[L:, :, 0]

    def logits(self, obs: torch.Tensor) -> torch.Tensor:
        return self(obs)[0]

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        return self(obs)[1]

    def act(
        self, obs: torch.Tensor, generator: torch.Generator
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sample actions: (actions (L, B) int64, log-probs (L, B), values (L, B))."""
        with torch.no_grad():
            logits, values = self(obs)
            logp_all = torch.log_softmax(logits, dim=-1)  # (L, B, A)
            L, B, A = logp_all.shape
            actions = torch.multinomial(
                logp_all.exp().reshape(L * B, A), 1, generator=generator
            ).reshape(L, B)
            logp = logp_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
            return actions, logp, values


def gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    episode_starts: torch.Tensor,
    last_values: torch.Tensor,
    last_dones: torch.Tensor,
    gamma: float,
    lam: float = GAE_LAMBDA,
) -> tuple[torch.Tensor, torch.Tensor]:
    """SB3's ``compute_returns_and_advantage`` on (L, E, T) tensors (T = rollout steps).

    ``episode_starts[..., t]``: obs t is the first of an episode; ``last_dones`` (L, E): the last step
    ended an episode.  Returns (advantages, returns), each (L, E, T).
    """
    T = rewards.shape[-1]
    adv = torch.zeros_like(rewards)
    last = torch.zeros_like(last_values)
    for t in reversed(range(T)):
        if t == T - 1:
            non_terminal, next_values = 1.0 - last_dones.float(), last_values
        else:
            non_terminal, next_values = 1.0 - episode_starts[..., t + 1].float(), values[..., t + 1]
        delta = rewards[..., t] + gamma * next_values * non_terminal - values[..., t]
        last = delta + gamma * lam * non_terminal * last
        adv[..., t] = last
    return adv, adv + values


@dataclass
class Rollout:
    """One rollout of every learner, flattened env-major like SB3's buffer: (L, N) with N = E * T."""

    obs: torch.Tensor  # (L, N, obs_dim) float
    actions: torch.Tensor  # (L, N) int64
    old_logp: torch.Tensor  # (L, N)
    old_values: torch.Tensor  # (L, N)
    advantages: torch.Tensor  # (L, N)
    returns: torch.Tensor  # (L, N)


def minibatches(
    data: Rollout,
    n_epochs: int,
    batch_size: int,
    permutations: list[torch.Tensor] | None = None,
    generator: torch.Generator | None = None,
) -> Iterator[tuple[torch.Tensor, ...]]:
    """SB3's minibatches of every learner: per epoch a permutation of the rollout, then contiguous
    slices of ``batch_size``, advantages normalised per minibatch and learner.

    ``permutations``: one (L, N) index tensor per epoch (tests pass SB3's); by default each learner
    draws its own random permutation per epoch.  The rollout is permuted once per epoch and the
    minibatches are then slices (SB3 indexes each minibatch: the same samples, fewer ops).
    Yields (obs (L, b, d), actions, advantages, old log-probs, returns (L, b) each).
    """
    L, N = data.actions.shape
    d = data.obs.shape[-1]
    for epoch in range(n_epochs):
        perm = (
            permutations[epoch]
            if permutations is not None
            else torch.argsort(torch.rand(L, N, generator=generator, device=data.obs.device), dim=1)
        )  # (L, N); on the data's device (a CUDA rollout needs a CUDA generator)
        obs_e = data.obs.gather(1, perm.unsqueeze(-1).expand(-1, -1, d))  # (L, N, d)
        act_e, adv_e = data.actions.gather(1, perm), data.advantages.gather(1, perm)
        logp_e, ret_e = data.old_logp.gather(1, perm), data.returns.gather(1, perm)
        for start in range(0, N, batch_size):
            mb = slice(start, start + batch_size)
            adv = adv_e[:, mb]  # (L, b)
            if adv.shape[1] > 1:
                adv = (adv - adv.mean(1, keepdim=True)) / (adv.std(1, keepdim=True) + 1e-8)
            yield obs_e[:, mb], act_e[:, mb], adv, logp_e[:, mb], ret_e[:, mb]


def ppo_loss(policy, obs, actions, adv, old_logp, returns) -> torch.Tensor:
    """SB3's PPO loss (entropy coefficient 0) of every learner, summed: each learner its own gradient."""
    logits, values = policy(obs)
    logp = torch.log_softmax(logits, dim=-1).gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    ratio = torch.exp(logp - old_logp)
    policy_loss = -torch.min(
        adv * ratio, adv * torch.clamp(ratio, 1 - CLIP_RANGE, 1 + CLIP_RANGE)
    ).mean(1)
    value_loss = ((returns - values) ** 2).mean(1)
    return (policy_loss + VF_COEF * value_loss).sum()  # (L,) summed


def clip_grad_norm_per_learner(
    params: list[torch.Tensor], max_norm: float, num_learners: int
) -> None:
    """``torch.nn.utils.clip_grad_norm_`` applied to each learner's parameters: its actor rows
    [l] and critic rows [L + l] of every stacked tensor count as one parameter vector."""
    with torch.no_grad():
        grads = [p.grad for p in params]
        norms = torch.stack(
            [torch.linalg.vector_norm(g, dim=(1, 2)) for g in grads]
        )  # (n_params, 2L)
        sq = norms.square().sum(0)  # (2L,)
        sq = sq[:num_learners] + sq[num_learners:]  # (L,) actor + critic of each learner
        coef = (
            torch.clamp(max_norm / (sq.sqrt() + 1e-6), max=1.0).repeat(2).view(-1, 1, 1)
        )  # (2L, 1, 1)
        torch._foreach_mul_(grads, [coef] * len(grads))


def make_optimizer(policy: StackedPolicy, lr: float) -> torch.optim.Optimizer:
    # fused: one kernel for all parameters (the same Adam; it is elementwise, so stacking is exact).
    return torch.optim.Adam(policy.parameters(), lr=lr, eps=ADAM_EPS, fused=True)


def ppo_update_autograd(
    policy: StackedPolicy,
    optimizer: torch.optim.Optimizer,
    data: Rollout,
    n_epochs: int,
    batch_size: int,
    permutations: list[torch.Tensor] | None = None,
    generator: torch.Generator | None = None,
) -> None:
    """SB3 ``PPO.train`` for every learner at once, with autograd: the reference update."""
    params = list(policy.parameters())
    for obs, actions, adv, old_logp, returns in minibatches(
        data, n_epochs, batch_size, permutations, generator
    ):
        optimizer.zero_grad(set_to_none=True)
        ppo_loss(policy, obs, actions, adv, old_logp, returns).backward()
        clip_grad_norm_per_learner(params, MAX_GRAD_NORM, policy.num_learners)
        optimizer.step()
