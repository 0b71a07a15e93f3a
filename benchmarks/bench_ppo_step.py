"""One stacked PPO minibatch step of the batched collector: hand-written gradients vs autograd.

    python benchmarks/bench_ppo_step.py [--learners 81] [--batch 50] [--repeats 3] [--json OUT]

The full-Darkroom shape by default: 81 learners (one per task, paper protocol), a rollout of
100 streams x 20 steps (N = 2,000), minibatches of 50, 2 epochs per timing.  Both paths run the same
``ppo_update`` on the same random rollout (the speed does not depend on the data); each timing is
repeated and the best kept, alternating the two paths so that load on a shared machine hits both.
Also reports the FLOP floor of a step at this machine's measured batched-matmul rate.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from lhf_hf.collection.batched_ppo import Rollout, StackedPolicy, make_optimizer, ppo_update


def rollout(L: int, N: int) -> Rollout:
    g = torch.Generator().manual_seed(0)
    return Rollout(
        obs=torch.randint(0, 9, (L, N, 2), generator=g).float(),
        actions=torch.randint(0, 5, (L, N), generator=g),
        old_logp=torch.log(torch.full((L, N), 0.2)) + 0.3 * torch.randn(L, N, generator=g),
        old_values=torch.randn(L, N, generator=g),
        advantages=torch.randn(L, N, generator=g),
        returns=torch.randn(L, N, generator=g),
    )


def step_ms(gradients: str, L: int, N: int, b: int, epochs: int = 2) -> float:
    policy = StackedPolicy(L, 2, 5, torch.Generator().manual_seed(1))
    opt = make_optimizer(policy, 3e-4)
    data, g = rollout(L, N), torch.Generator().manual_seed(2)
    ppo_update(policy, opt, data, 1, b, generator=g, gradients=gradients)  # warm-up, state init
    t = time.perf_counter()
    ppo_update(policy, opt, data, epochs, b, generator=g, gradients=gradients)
    return (time.perf_counter() - t) / (epochs * (N // b)) * 1e3


def matmul_floor_ms(L: int, b: int, hidden: int = 64) -> dict:
    """A step's FLOPs (forward, weight and input gradients of the three layers of 2L nets) and the
    time they take at the rate this machine's batched (b x 64) @ (64 x 64) matmul reaches."""
    n2, d, A = 2 * L, 2, 5
    macs = n2 * b * (d * hidden + hidden * hidden + hidden * A)  # one forward
    flops = 2 * macs * 3  # forward + weight gradient + input gradient
    x, w = torch.randn(n2, b, hidden), torch.randn(n2, hidden, hidden)
    torch.bmm(x, w)
    reps = 50
    t = time.perf_counter()
    for _ in range(reps):
        torch.bmm(x, w)
    rate = 2 * n2 * b * hidden * hidden * reps / (time.perf_counter() - t)
    return {"step_flops": flops, "bmm_gflops": rate / 1e9, "floor_ms": flops / rate * 1e3}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--learners", type=int, default=81)
    p.add_argument("--streams", type=int, default=100)
    p.add_argument("--n-steps", type=int, default=20)
    p.add_argument("--batch", type=int, default=50)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--json", default=None)
    a = p.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    L, N, b = a.learners, a.streams * a.n_steps, a.batch
    times = {"autograd": [], "manual": []}
    for _ in range(a.repeats):
        for mode in times:
            times[mode].append(step_ms(mode, L, N, b))
    best = {m: min(v) for m, v in times.items()}
    out = {
        "learners": L,
        "rollout": N,
        "batch": b,
        "torch_threads": torch.get_num_threads(),
        "step_ms": best,
        "all_ms": times,
        "speedup": best["autograd"] / best["manual"],
        **matmul_floor_ms(L, b),
    }
    print(json.dumps(out, indent=1))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
