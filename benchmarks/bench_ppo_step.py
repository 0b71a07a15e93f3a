"""One stacked PPO minibatch step of the batched collector: C++ kernel, hand-written torch gradients, autograd.

    python benchmarks/bench_ppo_step.py [--env darkroom] [--learners 81] [--repeats 3] [--json OUT]
                                        [--device cuda]

The env's paper PPO settings (docs/design.md 3: darkroom n_steps 20, batch 50, epochs 20;
dark-key-to-door 50 / 100 / 10), 81 learners by default (one per task, paper protocol, 100 streams),
2 epochs per timing.  Also projects the env's full paper dataset (every task x 100 histories x 1,000
transitions): its PPO minibatch steps, their FLOPs, the FLOP floor at the measured bmm rate, and the
update time at the measured per-learner step cost (rollouts, recording and writing not included).  Both paths run the same
``ppo_update`` on the same random rollout (the speed does not depend on the data); each timing is
repeated and the best kept, alternating the two paths so that load on a shared machine hits both.
Also reports the FLOP floor of a step at this machine's measured batched-matmul rate.
``--device cuda`` times the same update on a GPU (fp32, TF32 off: the same arithmetic), for the
question of what a GPU collector would gain; the collector itself runs its updates on the CPU.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from lhf_hf.collection import backend_verdict
from lhf_hf.collection.batched_ppo import Rollout, StackedPolicy, make_optimizer
from lhf_hf.collection.ppo_backends import ppo_update

DEVICE = torch.device("cpu")  # set from --device


def sync() -> None:
    if DEVICE.type == "cuda":
        torch.cuda.synchronize()


def rollout(L: int, N: int) -> Rollout:
    g = torch.Generator().manual_seed(0)
    data = Rollout(
        obs=torch.randint(0, 9, (L, N, 2), generator=g).float(),
        actions=torch.randint(0, 5, (L, N), generator=g),
        old_logp=torch.log(torch.full((L, N), 0.2)) + 0.3 * torch.randn(L, N, generator=g),
        old_values=torch.randn(L, N, generator=g),
        advantages=torch.randn(L, N, generator=g),
        returns=torch.randn(L, N, generator=g),
    )
    return Rollout(*(getattr(data, f).to(DEVICE) for f in data.__dataclass_fields__))


def step_ms(gradients: str, L: int, N: int, b: int, epochs: int = 2) -> float:
    policy = StackedPolicy(L, 2, 5, torch.Generator().manual_seed(1)).to(DEVICE)
    opt = make_optimizer(policy, 3e-4)
    data, g = rollout(L, N), torch.Generator(device=DEVICE).manual_seed(2)
    ppo_update(policy, opt, data, 1, b, generator=g, gradients=gradients)  # warm-up, state init
    sync()
    t = time.perf_counter()
    ppo_update(policy, opt, data, epochs, b, generator=g, gradients=gradients)
    sync()
    return (time.perf_counter() - t) / (epochs * (N // b)) * 1e3


def step_flops(L: int, b: int, d: int = 2, A: int = 5, hidden: int = 64) -> int:
    """FLOPs one stacked minibatch step needs: for each of the L actors (head: A logits) and L critics
    (head: 1 value), the forward matmuls, every layer's weight gradient, and the input gradients of
    layers 2 and 3 (layer 1's input gradient is not needed).  Counted as 2 FLOPs per multiply-add;
    biases, activations, the loss and Adam are left out (they are not matmuls)."""

    def net(out: int) -> int:  # multiply-adds per row
        fwd = d * hidden + hidden * hidden + hidden * out
        return 2 * fwd + hidden * hidden + hidden * out  # forward + weight grads + input grads

    return 2 * L * b * (net(A) + net(1))


def minibatch_steps_per_learner(cfg) -> int:
    """Sequential PPO minibatch steps of one paper-protocol learner over a whole collection (the last
    rollout is not followed by an update: it cannot change the data)."""
    ppo = cfg.ppo
    return (
        (cfg.steps // ppo.n_steps - 1)
        * ppo.n_epochs
        * (cfg.histories * ppo.n_steps // ppo.batch_size)
    )


def matmul_floor_ms(L: int, b: int, hidden: int = 64) -> dict:
    """A step's FLOPs and the time they take at the rate this machine's batched (b x 64) @ (64 x 64)
    matmul reaches."""
    n2 = 2 * L
    flops = step_flops(L, b, hidden=hidden)
    x = torch.randn(n2, b, hidden, device=DEVICE)
    w = torch.randn(n2, hidden, hidden, device=DEVICE)
    torch.bmm(x, w)
    reps = 50
    sync()
    t = time.perf_counter()
    for _ in range(reps):
        torch.bmm(x, w)
    sync()
    rate = 2 * n2 * b * hidden * hidden * reps / (time.perf_counter() - t)
    return {"step_flops": flops, "bmm_gflops": rate / 1e9, "floor_ms": flops / rate * 1e3}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--env", default="darkroom", help="gridworld env id (its paper PPO settings)")
    p.add_argument("--learners", type=int, default=81)
    p.add_argument("--streams", type=int, default=100)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--json", default=None)
    p.add_argument("--device", default="cpu", help="cpu or cuda (fp32, TF32 off)")
    a = p.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    global DEVICE
    DEVICE = torch.device(a.device)
    torch.backends.cuda.matmul.allow_tf32 = False  # exact fp32, the CPU's arithmetic
    from lhf_hf.configs.collect import CollectConfig
    from lhf_hf.envs import get_spec

    cfg = CollectConfig(env_id=a.env, collector="batched")
    spec, ppo = get_spec(a.env), cfg.ppo
    L, N, b = a.learners, a.streams * ppo.n_steps, ppo.batch_size
    # the C++ kernel (the collector's default backend on the CPU) vs the torch paths
    times = {"autograd": [], "manual": []} | ({"kernel": []} if DEVICE.type == "cpu" else {})
    for _ in range(a.repeats):
        for mode in times:
            times[mode].append(step_ms(mode, L, N, b))
    best = {m: min(v) for m, v in times.items()}
    floor = matmul_floor_ms(L, b)
    # the full paper dataset: every task's learner does (steps / n_steps - 1) updates (the last
    # rollout's update is skipped) of n_epochs x N / b minibatch steps
    tasks = spec.num_tasks
    steps_per_learner = minibatch_steps_per_learner(cfg)
    total_flops = tasks * steps_per_learner * step_flops(1, b)
    fastest = "kernel" if "kernel" in best else "manual"
    per_learner_step_s = best[fastest] / 1e3 / L
    projection = {
        "tasks": tasks,
        "minibatch_steps_per_learner": steps_per_learner,
        "update_flops": total_flops,
        "flop_floor_s": total_flops / (floor["bmm_gflops"] * 1e9),
        "updates_at_measured_step_s": tasks * steps_per_learner * per_learner_step_s,
        "measured_step": fastest,
    }
    out = {
        "env": a.env,
        "ppo": {"n_steps": ppo.n_steps, "batch_size": b, "n_epochs": ppo.n_epochs},
        "learners": L,
        "rollout": N,
        "batch": b,
        "torch_threads": torch.get_num_threads(),
        "device": str(DEVICE)
        + (f" ({torch.cuda.get_device_name(DEVICE)})" if DEVICE.type == "cuda" else ""),
        "torch": torch.__version__,
        **({"machine": backend_verdict.machine()} if DEVICE.type == "cpu" else {}),
        "step_ms": best,
        "all_ms": times,
        "speedup": best["autograd"] / best["manual"],
        **({"kernel_vs_manual": best["manual"] / best["kernel"]} if "kernel" in best else {}),
        "kernel_gflops": step_flops(L, b) / best["kernel"] / 1e6 if "kernel" in best else None,
        **floor,
        "full_dataset": projection,
    }
    print(json.dumps(out, indent=1))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
