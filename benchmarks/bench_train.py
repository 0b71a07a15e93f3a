"""Training throughput: ``transformers.Trainer`` vs a plain PyTorch loop (same model, same batches).

    python benchmarks/bench_train.py --dataset data/darkroom [--steps 30] [--rounds 3] [--json OUT]

Targets (docs/design.md 9, issue "model family"): Trainer >= 0.9x the plain loop's tokens/s on the
paper preset (AD, context 80, batch 64), and building a batch (sampler + collator) < 5% of a step.
Also measured: the training attention (``lhf_sdpa``, lhf_hf/modeling/train_attention.py, the
default) against torch's SDPA in the plain loop, and DICP (two tokens per transition);
``--all-variants`` adds the ones tried and dropped (eager attention, ``torch.compile``, a
data-loading worker).  Each variant starts from the same seed and draws the same windows.  The
plain loop, the Trainer and the torch-SDPA loop run in ``--rounds`` rounds, in an order rotated
each round, and each ratio is the median of the per-round ratios: a drift of a shared machine's
speed within a round hits every variant, and one slow round does not decide the verdict.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import platform
import statistics
import tempfile
import time

import torch
from transformers import TrainerCallback, get_cosine_schedule_with_warmup

from lhf_hf.configs import TrainConfig
from lhf_hf.training import build_trainer


class _StepTimer(TrainerCallback):
    def __init__(self, warmup: int):
        self.warmup, self.t0, self.t1 = warmup, None, None

    def on_step_end(self, args, state, control, **kwargs):
        if state.global_step == self.warmup:
            self.t0 = time.perf_counter()
        self.t1 = time.perf_counter()


def batches(trainer, n: int):
    """The first ``n`` batches the Trainer's own sampler and collator produce."""
    loader = trainer.get_train_dataloader()
    it = iter(loader)
    return [next(it) for _ in range(n)]


def plain_loop(trainer, data, warmup: int, compile_model: bool = False) -> float:
    """AdamW + cosine + clipping, the Trainer's settings, in a bare loop; seconds per step."""
    a = trainer.args
    torch.manual_seed(a.seed)
    model = type(trainer.model)(trainer.model.config)
    model.train()
    step_fn = torch.compile(model) if compile_model else model
    decay = [p for n, p in model.named_parameters() if p.ndim >= 2]
    no_decay = [p for n, p in model.named_parameters() if p.ndim < 2]
    opt = torch.optim.AdamW(
        [
            {"params": decay, "weight_decay": a.weight_decay},
            {"params": no_decay, "weight_decay": 0.0},
        ],
        lr=a.learning_rate,
        betas=(a.adam_beta1, a.adam_beta2),
        eps=a.adam_epsilon,
    )
    sched = get_cosine_schedule_with_warmup(opt, 0, len(data))
    t0 = None
    for i, batch in enumerate(data):
        if i == warmup:
            t0 = time.perf_counter()
        loss = step_fn(**batch).loss
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), a.max_grad_norm)
        opt.step()
        sched.step()
        opt.zero_grad(set_to_none=True)
    return (time.perf_counter() - t0) / (len(data) - warmup)


def trainer_run(cfg: TrainConfig, warmup: int, **overrides) -> float:
    trainer, _ = build_trainer(cfg)
    for k, v in overrides.items():
        setattr(trainer.args, k, v)
    timer = _StepTimer(warmup)
    trainer.add_callback(timer)
    trainer.args.disable_tqdm = True
    trainer.train()
    return (timer.t1 - timer.t0) / (cfg.max_steps - warmup)


@contextlib.contextmanager
def attention(trainer, name: str):
    """The plain loop's model (built from the Trainer's config) with another attention function."""
    config = trainer.model.config
    saved = config._attn_implementation
    config._attn_implementation = name
    try:
        yield
    finally:
        config._attn_implementation = saved


def batching_time(trainer, n: int) -> float:
    loader = trainer.get_train_dataloader()
    it = iter(loader)
    next(it)
    t0 = time.perf_counter()
    for _ in range(n):
        next(it)
    return (time.perf_counter() - t0) / n


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--dataset", required=True)
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--warmup", type=int, default=5)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--rounds", type=int, default=3, help="alternating plain / Trainer rounds")
    p.add_argument("--json", default=None)
    p.add_argument(
        "--all-variants",
        action="store_true",
        help="also the variants tried and dropped: a data-loading worker, eager attention, "
        "torch.compile",
    )
    args = p.parse_args()
    tmp = tempfile.mkdtemp(prefix="bench-train-")
    results = {
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "machine": platform.processor() or platform.machine(),
        "steps": args.steps,
        "rounds": args.rounds,
        "warmup": args.warmup,
        "batch_size": args.batch_size,
        "variants": {},
    }

    def cfg(objective: str) -> TrainConfig:
        return TrainConfig(
            dataset=args.dataset,
            objective=objective,
            out=f"{tmp}/{objective}",
            preset="paper",
            max_steps=args.steps,
            batch_size=args.batch_size,
            save_steps=10**6,
            logging_steps=10**6,
            overwrite=True,
        )

    for objective in ("ad", "dicp"):
        c = cfg(objective)
        trainer, _ = build_trainer(c)
        tokens = c.batch_size * trainer.model.config.max_tokens
        data = batches(trainer, args.steps)
        t_batch = batching_time(trainer, 20)
        rows = {}
        rounds = []  # {variant: s/step} per round
        variants = ("plain", "trainer", "plain_torch_sdpa")
        for r in range(args.rounds):
            # rotate the order, so that a drift of a shared machine's speed hits every variant
            order = variants[r % 3 :] + variants[: r % 3]
            t = {}
            for variant in order:
                if variant == "plain":
                    t[variant] = plain_loop(trainer, data, args.warmup)
                elif variant == "trainer":
                    t[variant] = trainer_run(c, args.warmup)
                else:  # the baseline: torch's SDPA in training too (draws dropout with bernoulli_)
                    with attention(trainer, "sdpa"):
                        t[variant] = plain_loop(trainer, data, args.warmup)
            rounds.append(t)
        for v in variants:
            rows[v] = statistics.median(t[v] for t in rounds)
        if args.all_variants:
            # batches built in a worker process while the model steps (prefetch), not in the step
            rows["trainer_worker"] = trainer_run(
                c, args.warmup, dataloader_num_workers=1, dataloader_persistent_workers=True
            )
            if objective == "ad":
                with attention(trainer, "eager"):
                    rows["plain_eager"] = plain_loop(trainer, data, args.warmup)
                try:
                    rows["plain_compiled"] = plain_loop(
                        trainer, data, args.warmup, compile_model=True
                    )
                except Exception as exc:  # a missing compiler must not hide the other numbers
                    rows["plain_compiled"] = None
                    results.setdefault("errors", {})["plain_compiled"] = repr(exc)[:300]
        out = {k: {"s_per_step": v, "tokens_per_s": tokens / v} for k, v in rows.items() if v}
        out["batching_s"] = t_batch
        out["batching_share_of_trainer_step"] = t_batch / rows["trainer"]
        out["rounds_s_per_step"] = rounds
        out["trainer_vs_plain_per_round"] = [t["plain"] / t["trainer"] for t in rounds]
        out["trainer_vs_plain"] = statistics.median(out["trainer_vs_plain_per_round"])
        # the training attention (lhf_hf/modeling/train_attention.py) against torch's SDPA
        out["speedup_vs_torch_sdpa_per_round"] = [
            t["plain_torch_sdpa"] / t["plain"] for t in rounds
        ]
        out["speedup_vs_torch_sdpa"] = statistics.median(out["speedup_vs_torch_sdpa_per_round"])
        out["tokens_per_step"] = tokens
        results["variants"][objective] = out
        print(objective, json.dumps(out, indent=1))
    if args.json:
        from lhf_hf.utils.io import write_json_atomic

        write_json_atomic(results, args.json)


if __name__ == "__main__":
    main()
