"""The stacked PPO equals Stable-Baselines3's PPO: same GAE, same update from the same state."""

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.vec_env import DummyVecEnv

from lhf_hf.collection.batched_ppo import (
    Rollout,
    StackedPolicy,
    gae,
    make_optimizer,
    ppo_loss,
)
from lhf_hf.collection.ppo_backends import ppo_update
from lhf_hf.collection.ppo_manual import ManualGradients
from lhf_hf.envs import make

from .rollouts import random_rollout


def test_gae_equals_sb3():
    rng = np.random.default_rng(0)
    T, E = 20, 3
    env = make("darkroom", 0)
    buf = RolloutBuffer(
        T, env.observation_space, env.action_space, gamma=0.99, gae_lambda=0.95, n_envs=E
    )
    rewards, values = (
        rng.normal(size=(T, E)).astype(np.float32),
        rng.normal(size=(T, E)).astype(np.float32),
    )
    starts = rng.random((T, E)) < 0.2
    for t in range(T):
        buf.add(
            np.zeros((E, 2)),
            np.zeros((E, 1)),
            rewards[t],
            starts[t],
            torch.tensor(values[t]),
            torch.zeros(E),
        )
    last_values, dones = rng.normal(size=E).astype(np.float32), np.array([True, False, True])
    buf.compute_returns_and_advantage(torch.tensor(last_values), dones)
    to = lambda x: torch.tensor(x).T.unsqueeze(0)  # noqa: E731 - (T, E) -> (1, E, T)
    adv, ret = gae(
        to(rewards),
        to(values),
        to(starts),
        torch.tensor(last_values)[None],
        torch.tensor(dones)[None],
        0.99,
    )
    np.testing.assert_allclose(adv[0].T.numpy(), buf.advantages, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ret[0].T.numpy(), buf.returns, rtol=1e-5, atol=1e-6)


def _copy_sb3_into(policy: StackedPolicy, model: PPO, learner: int) -> None:
    sd = model.policy.state_dict()
    names = {
        "actor": ["mlp_extractor.policy_net.0", "mlp_extractor.policy_net.2", "action_net"],
        "critic": ["mlp_extractor.value_net.0", "mlp_extractor.value_net.2", "value_net"],
    }
    L = policy.num_learners
    with torch.no_grad():
        for part, layers in names.items():
            row = learner if part == "actor" else L + learner
            for i, name in enumerate(layers):
                w = sd[f"{name}.weight"].T  # (in, out)
                policy.net.weights[i][row, :, : w.shape[1]] = w
                policy.net.biases[i][row, 0, : w.shape[1]] = sd[f"{name}.bias"]


def _compare(policy: StackedPolicy, model: PPO, learner: int, atol: float) -> None:
    ours = StackedPolicy(1, 2, 5, torch.Generator().manual_seed(0))
    _copy_sb3_into(ours, model, 0)
    for a, b in zip(policy.parameters(), ours.parameters(), strict=True):
        np.testing.assert_allclose(
            a[learner].detach().numpy(), b[0].detach().numpy(), atol=atol, rtol=0
        )


def test_forward_and_init_match_sb3_architecture():
    model = PPO("MlpPolicy", DummyVecEnv([lambda: make("darkroom", 3)]), seed=0, device="cpu")
    policy = StackedPolicy(2, 2, 5, torch.Generator().manual_seed(1))
    _copy_sb3_into(policy, model, 1)
    obs = torch.tensor([[4.0, 4.0], [0.0, 8.0], [3.0, 1.0]])
    with torch.no_grad():
        dist = model.policy.get_distribution(obs)
        values = model.policy.predict_values(obs).squeeze(-1)
        logits = policy.logits(obs.expand(2, -1, -1))[1]
        np.testing.assert_allclose(
            torch.log_softmax(logits, -1).numpy(), dist.distribution.logits.numpy(), atol=1e-6
        )
        np.testing.assert_allclose(
            policy.value(obs.expand(2, -1, -1))[1].numpy(), values.numpy(), atol=1e-6
        )
    # SB3's init: orthogonal rows/cols scaled by the gain, zero biases (learner 0: our own init)
    for row, head_gain, head_out in ((0, 0.01, 5), (2, 1.0, 1)):  # actor row 0, critic row L + 0
        for i, gain in enumerate([np.sqrt(2), np.sqrt(2), head_gain]):
            m = policy.net.weights[i][row].detach().T  # (out, in)
            if i == 2:
                assert float(m[head_out:].abs().sum()) == 0  # padded critic head
                m = m[:head_out]
            gram = m @ m.T if m.shape[0] <= m.shape[1] else m.T @ m
            np.testing.assert_allclose(gram.numpy(), gain**2 * np.eye(gram.shape[0]), atol=1e-5)
    assert all(
        float(b.detach().abs().max()) == 0
        for b in StackedPolicy(2, 2, 5, torch.Generator()).net.biases
    )


@pytest.mark.parametrize("gradients", ["kernel", "manual", "autograd"])
@pytest.mark.parametrize("n_epochs, batch_size", [(2, 50), (3, 64)])
@pytest.mark.filterwarnings("ignore:You have specified a mini-batch size")
def test_one_update_equals_sb3_train(n_epochs, batch_size, gradients):
    E, T = 4, 40
    model = PPO(
        "MlpPolicy",
        DummyVecEnv([lambda: make("darkroom", 30)] * E),
        n_steps=T,
        batch_size=batch_size,
        n_epochs=n_epochs,
        seed=3,
        device="cpu",
    )
    _, callback = model._setup_learn(T * E, callback=None)
    callback.on_training_start(locals(), globals())
    model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=T)
    rb = model.rollout_buffer
    flat = lambda x: torch.tensor(np.swapaxes(x, 0, 1).reshape(E * T, *x.shape[2:]))[None]  # noqa: E731 - env-major like SB3
    data = Rollout(
        obs=flat(rb.observations).float(),
        actions=flat(rb.actions[..., 0]).long(),
        old_logp=flat(rb.log_probs),
        old_values=flat(rb.values),
        advantages=flat(rb.advantages),
        returns=flat(rb.returns),
    )
    # Learner 1 of a stack of 3 gets SB3's weights; the others are distractors with their own weights.
    policy = StackedPolicy(3, 2, 5, torch.Generator().manual_seed(5))
    _copy_sb3_into(policy, model, 1)
    data3 = Rollout(
        *(
            torch.cat([x, x, x])
            for x in (
                data.obs,
                data.actions,
                data.old_logp,
                data.old_values,
                data.advantages,
                data.returns,
            )
        )
    )
    np.random.seed(11)
    perms = [torch.tensor(np.random.permutation(E * T)) for _ in range(n_epochs)]
    before = [p.detach().clone() for p in model.policy.parameters()]
    np.random.seed(11)  # SB3's buffer draws np.random.permutation once per epoch
    model.train()
    moved = max(
        float((p.detach() - b).abs().max())
        for p, b in zip(model.policy.parameters(), before, strict=True)
    )
    assert moved > 50 * 2e-5, "the update must move the weights well beyond the tolerance"
    ppo_update(
        policy,
        make_optimizer(policy, 3e-4),
        data3,
        n_epochs,
        batch_size,
        permutations=[p.expand(3, -1) for p in perms],
        gradients=gradients,
    )
    _compare(policy, model, 1, atol=2e-5)


def test_manual_gradients_equal_autograd():
    """One minibatch: the hand-written gradient of every parameter equals autograd's, with ratios
    inside and outside the clip range and advantages of both signs."""
    L, b = 4, 30
    policy = StackedPolicy(L, 2, 5, torch.Generator().manual_seed(1))
    data = random_rollout(L, b)
    adv = data.advantages
    adv = (adv - adv.mean(1, keepdim=True)) / (adv.std(1, keepdim=True) + 1e-8)
    args = (data.obs, data.actions, adv, data.old_logp, data.returns)
    ppo_loss(policy, *args).backward()
    expected = [p.grad.clone() for p in policy.parameters()]
    with torch.no_grad():
        logits, _ = policy(data.obs)
        logp = torch.log_softmax(logits, -1).gather(-1, data.actions[..., None])[..., 0]
        ratio = torch.exp(logp - data.old_logp)
    assert bool(((ratio - 1).abs() > 0.2).any()) and bool(((ratio - 1).abs() < 0.2).any())
    ManualGradients(policy)(*args)
    for p, e in zip(policy.parameters(), expected, strict=True):
        torch.testing.assert_close(p.grad, e, rtol=1e-5, atol=1e-7)
    # the padded critic head columns get no gradient, as with autograd
    assert float(policy.net.weights[2].grad[L:, :, 1:].abs().max()) == 0.0


def test_manual_update_equals_autograd_update_over_many_steps():
    """Two epochs of minibatch steps (Adam through FusedAdamStep) stay within float rounding of the
    autograd path with torch's own Adam.step."""
    L, N = 3, 200
    data = random_rollout(L, N, seed=2)
    out = {}
    for gradients in ("autograd", "manual"):
        policy = StackedPolicy(L, 2, 5, torch.Generator().manual_seed(4))
        opt = make_optimizer(policy, 3e-4)
        ppo_update(
            policy,
            opt,
            data,
            2,
            25,
            generator=torch.Generator().manual_seed(5),
            gradients=gradients,
        )
        out[gradients] = [p.detach().clone() for p in policy.parameters()]
        assert all(int(st["step"]) == 16 for st in opt.state.values())
    for a, m in zip(out["autograd"], out["manual"], strict=True):
        torch.testing.assert_close(m, a, rtol=1e-5, atol=1e-6)


def test_unknown_gradients_mode_is_an_error():
    policy = StackedPolicy(1, 2, 5, torch.Generator())
    with pytest.raises(ValueError, match="gradients must be one of"):
        ppo_update(
            policy, make_optimizer(policy, 3e-4), random_rollout(1, 10), 1, 5, gradients="jax"
        )


def test_initial_weights_do_not_depend_on_the_thread_count():
    old = torch.get_num_threads()
    params = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            policy = StackedPolicy(6, 2, 5, torch.Generator().manual_seed(3))
            params.append([p.detach().clone() for p in policy.stacked_params()])
            assert torch.get_num_threads() == threads
    finally:
        torch.set_num_threads(old)
    for a, b in zip(*params, strict=True):
        assert torch.equal(a, b)  # bit for bit
