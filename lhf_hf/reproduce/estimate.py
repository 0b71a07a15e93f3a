"""``lhf reproduce EXPERIMENT --preset P --estimate``: what would run, what is cached, how long.

Every stage carries a ``Cost``: what its time scales with (``units``) and the kind of work a
seconds-per-unit rate holds for (``key``):

- collect: transitions (tasks x histories x steps); key: env, collector, algo.
- derive / filter: transitions of the dataset read; key: the kind.
- train: tokens (max_steps x batch x tokens per item); key: objective, model preset, attention.
- evaluate: env-steps (episodes x tasks x horizon; with planning, the planned ones); key: env,
  objective, preset, plan, context.
- train and evaluate keys end in ``|ctxN`` when the model's context is not the env's default
  (``model_context``): attention per token and a window's recomputation grow with it.

The keys' text layout is ``rate_key.RateKey``'s.

An env with no rate of a kind borrows its twin's (``twins``: the same declared
``EnvSpec.cost_class``, spaces, horizon and default context: the Meta-World ML1 tasks), and the
basis names the env it was measured on.

A finished stage records its cost, its wall time, the CPU model and its torch threads in
``stage.json``, so every reproduction measures rates for the next estimate; the time of the part
that scales (a training's steps, an evaluation's rollout) is read from the stage's own outputs and
the rest is a per-stage start-up cost (``work_seconds``): estimate = start-up + rate x units.  A stage's rate is,
in order: the mean over finished stages with its key on this CPU model at the same thread count
(``this machine``), the same at the other thread count converted by the measured factor below, the
reference tables shipped in ``rates.json`` (one per machine it was measured on: the one of this CPU
model, else of this instruction set, ``load_reference``), or none (its time is then missing from the
total, which says so).  Rates are per unit, so a longer training or a longer
collection is predicted linearly (attention's cost grows with the context, and for the batched
collector the chunk size matters, which is why the env is in the keys).

With ``jobs > 1`` the wall time is a simulation of ``parallel.run_stages``'s schedule on these
durations (one thread per training / evaluation).
"""

from __future__ import annotations

import heapq
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from lhf_hf.collection.backend_verdict import cpu_model, instruction_set
from lhf_hf.configs import CollectConfig, EvalConfig, TrainConfig
from lhf_hf.envs import get_spec, list_env_ids
from lhf_hf.envs.registry import describe_space
from lhf_hf.errors import UserError
from lhf_hf.evaluation.evaluate import resolve_tasks
from lhf_hf.training.trainer import model_config_for, sequence_length
from lhf_hf.utils.io import read_json

from .parallel import IN_PROCESS, can_start, start_order
from .rate_key import RateKey
from .stages import (
    COST_FORMAT,
    DONE_FILE,
    RECORD_FILE,
    Cost,
    Stage,
    done_record,
    finite_number,
)

#: A training or evaluation with 1 thread takes this many times its 2-thread time when two run
#: side by side (190-198 s vs 124-126 s, BENCHMARKS.md "Reproduce: stages side by side", Intel).
THREAD_FACTOR = 1.53
REFERENCE = Path(__file__).resolve().parent / "rates.json"
#: A child process's imports before its stage starts (``--jobs`` > 1), which the child's own
#: ``stage.json`` cannot see: 5-6 s per stage (BENCHMARKS.md, "Reproduce: stages side by side").
CHILD_START_S = 5.0
#: More torch threads than any machine here has: a stage record above it is damaged.
MAX_THREADS = 4096


@dataclass(frozen=True)
class Rate:
    seconds_per_unit: float  # of the part that scales with the units
    overhead_s: float  # start-up seconds of one stage
    basis: str  # where it comes from, in words
    stages: int  # how many measured stages it averages

    def seconds(self, units: float) -> float:
        return self.overhead_s + self.seconds_per_unit * units


# ---- what each stage's time scales with
def collect_cost(cfg: CollectConfig) -> Cost:
    key = RateKey("collect", cfg.env_id, (cfg.collector, cfg.algo))
    return Cost(str(key), float(len(cfg.tasks) * cfg.histories * cfg.steps))


def data_cost(kind: str, transitions: float) -> Cost:
    return Cost(kind, transitions)


def model_context(env: str, cfg: TrainConfig) -> int | None:
    """The model's context length when it is not the env's default, else None (``RateKey``'s
    context: a token's attention and an evaluation step's window grow with the context, so a rate
    holds for one context only)."""
    spec = get_spec(env)
    context = cfg.context_length or spec.context_length
    return None if context == spec.context_length else context


def train_cost(env: str, cfg: TrainConfig) -> Cost:
    config = model_config_for(get_spec(env), cfg, has_optimal=True)
    tokens = sequence_length(cfg, config) * config.tokens_per_transition
    key = RateKey("train", env, (cfg.objective, cfg.preset, cfg.attention), model_context(env, cfg))
    return Cost(str(key), float(cfg.max_steps * cfg.batch_size * tokens))


def eval_cost(
    env: str, objective: str, train: TrainConfig, cfg: EvalConfig, split_seed: int
) -> Cost:
    """Env-steps; with planning on discrete actions, the planned ones: the beam search starts once
    the context holds K transitions (``rollout``), and a planned step costs tens of model-free
    ones, so the first K steps of each task are left out.  On continuous actions every env-step
    counts, as without planning: the greedy search scores its samples in one more backbone call,
    10 query tokens against the cached context, small beside the step's window (Meta-World
    Reach-Wall, 50 tasks x 7 episodes, 5,050 planned actions: 306.2 s with planning, 306.4 s
    without; BENCHMARKS.md), so its time scales with all steps."""
    spec = get_spec(env)
    tasks = len(resolve_tasks(env, cfg.tasks, split_seed))
    steps = cfg.episodes * spec.horizon
    if cfg.plan and spec.is_discrete:
        steps = max(steps - (train.context_length or spec.context_length), 0)
    plan = "plan" if cfg.plan else "no plan"
    context = (
        cfg.context
        if cfg.context != "auto"
        else ("cache" if train.attention == "band" else "window")
    )
    fields = (objective, train.preset, plan, context)
    return Cost(
        str(RateKey("evaluate", env, fields, model_context(env, train))),
        float(steps * tasks * cfg.rollouts),
    )


# ---- rates and the estimate
def current_key(rec: dict, work: Path) -> str | None:
    """A record's cost key as ``train_cost`` / ``eval_cost`` make it now.  Records written before
    keys named a non-default context (no ``format`` in their cost) were keyed as if every model
    had its env's default one: a training's context is read from its config, an evaluation's
    from its training's record (``model`` is the training's hash); None when that cannot be
    read (the record is then no rate rather than a rate filed under another context)."""
    cost = rec["cost"]
    key = cost["key"]
    try:
        parsed = RateKey.parse(key)
    except ValueError:
        return key  # not a key this version writes: no stage will ask for its rate
    if cost.get("format") == COST_FORMAT or parsed.kind not in ("train", "evaluate"):
        return key
    if parsed.env is None:
        return key
    try:
        spec = get_spec(parsed.env)
    except KeyError:
        return key  # an env no longer registered: nothing to estimate with it anyway
    config = rec.get("config")
    if parsed.kind == "evaluate":
        model = config.get("model") if isinstance(config, dict) else None
        config = None
        for name in (DONE_FILE, RECORD_FILE) if isinstance(model, str) and model else ():
            try:
                config = read_json(work / "train" / model[:12] / name)["config"]
                break
            except (OSError, ValueError, KeyError, TypeError):
                continue
    if not isinstance(config, dict):
        return None
    context = config.get("context_length")
    if context is None or context == spec.context_length:
        return key
    if not isinstance(context, int) or isinstance(context, bool) or context < 1:
        return None
    return str(parsed.at(context))


def measured_stages(work: str | Path) -> list[dict]:
    """Every finished stage under ``work`` that recorded its cost (older ones did not), with
    ``work_s``: the seconds of the part that scales with the units (``work_seconds``).  A mark that
    is not a cost record of the expected shape (damaged, or edited by hand) is left out: that stage
    is no rate, and whether it runs again is the stage cache's business."""
    out = []
    for path in sorted(Path(work).glob(f"*/*/{DONE_FILE}")):
        rec = done_record(path.parent)  # None: damaged, edited, or another stage's record
        if rec is None or not _cost_record(rec):
            continue  # no rate: that stage runs again anyway, or recorded no cost
        key = current_key(rec, Path(work))
        if key is None:
            continue  # an older record whose context cannot be told
        rec["cost"] = {**rec["cost"], "key": key}
        work_s = work_seconds(rec.get("kind", ""), path.parent)
        usable = work_s is not None and math.isfinite(work_s) and work_s > 0
        rec["work_s"] = min(work_s, rec["wall_s"]) if usable else rec["wall_s"]
        out.append(rec)
    return out


def _cost_record(rec) -> bool:
    """Whether a ``stage.json`` holds a usable cost: a string key, positive units and wall time,
    integer threads, and a string kind and CPU model where given."""
    if not isinstance(rec, dict) or not isinstance(cost := rec.get("cost"), dict):
        return False
    return (
        isinstance(cost.get("key"), str)
        and finite_number(cost.get("units")) and cost["units"] > 0
        and finite_number(rec.get("wall_s")) and rec["wall_s"] > 0
        and isinstance(t := rec.get("threads", 0), int) and not isinstance(t, bool)
        and 0 <= t <= MAX_THREADS
        and all(isinstance(rec.get(f, ""), str) for f in ("kind", "cpu", "isa"))
    )  # fmt: skip


def work_seconds(kind: str, folder: Path) -> float | None:
    """The seconds a stage spent on the work its units count, from its own outputs: a training's
    ``train_runtime`` (Trainer), an evaluation's rollout ``wall_s``.  The rest of the stage's wall
    time (imports, loading the data, building and saving the model) is a start-up cost that does
    not grow with the units: a 40-step calibration training or a one-episode evaluation is mostly
    start-up, so the two are told apart."""
    try:
        if kind == "train":
            log = read_json(folder / "model" / "training_log.json")
            runtimes = [e["train_runtime"] for e in log if "train_runtime" in e]
            return float(runtimes[-1]) if runtimes else None
        if kind == "evaluate":
            return float(read_json(folder / "eval" / "eval_results.json")["wall_s"])
    except (OSError, ValueError, KeyError, TypeError, OverflowError):
        return None
    return None


def rate_threads(key: str, threads: int) -> int:
    """The thread count a rate of ``key`` is filed under: a training's or evaluation's own, 0
    (any) for a collection, derivation or filter, whose time does not depend on torch's threads:
    their stages pool into one rate whatever count they ran with."""
    return threads if _threaded(key) else 0


def rate_table(records: Sequence[dict]) -> dict[tuple[str, str, int], dict]:
    """``(key, cpu, threads) -> {"seconds_per_unit", "overhead_s", "stages"}``: per group, the
    rate of the scaling part, the mean start-up seconds and the units behind the rate
    (``threads`` as ``rate_threads`` files it).

    The rate is the group's seconds over its units (not the mean of per-stage rates): it predicts
    long stages, and a short stage's time is mostly start-up where ``work_seconds`` cannot tell the
    two apart (a collection, a derivation, a filter), so weighing stages by their units keeps a
    calibration stage from setting it (Meta-World Reach-Wall's SB3 collection: 8,000 transitions in
    12.7 s for calibration, 1,000,000 in 355 s in a table; the mean of the two rates predicted
    the table's collection at 4.5x its time, the units-weighted one within 3 %)."""
    groups: dict[tuple[str, str, int], list[dict]] = {}
    for r in records:
        key = r["cost"]["key"]
        k = (key, r.get("cpu", "?"), rate_threads(key, int(r.get("threads", 0))))
        groups.setdefault(k, []).append(r)
    out = {}
    for k, v in groups.items():
        units = sum(float(r["cost"]["units"]) for r in v)
        out[k] = {
            "seconds_per_unit": sum(r["work_s"] for r in v) / units,
            "overhead_s": sum(r["wall_s"] - r["work_s"] for r in v) / len(v),
            "stages": len(v),
            "units": units,
        }
    return out


def reference_machines(data) -> list[dict]:
    """The machines of a rates table: ``{"machines": [...]}``, or one machine's table (the older
    single-machine form), each checked (``check_machine``).  Anything else (``{}``, a list, a
    results file) raises ``ValueError`` saying what is wrong, so a writer never takes it for an
    empty table and replaces it."""
    if not isinstance(data, dict):
        raise UserError(f"a rates table is a JSON object, not {type(data).__name__}")
    if "machines" in data:
        machines = data["machines"]
        if not isinstance(machines, list) or not machines:
            raise UserError('"machines" must be a non-empty list of machine tables')
    elif "rates" in data:
        machines = [data]
    else:
        raise UserError('neither "machines" nor "rates" is there')
    for i, m in enumerate(machines):
        check_machine(m, f"machine {i}")
    return list(machines)


#: Fields of one rate in a rates table: name -> (types, required).
_RATE_FIELDS = {
    "key": ((str,), True),
    "threads": ((int,), True),
    "seconds_per_unit": ((int, float), True),
    "stages": ((int,), True),
    "overhead_s": ((int, float), False),
    "units": ((int, float), False),
}


def check_machine(m, where: str = "machine") -> None:
    """``ValueError`` unless ``m`` is one machine's table: ``cpu`` / ``isa`` strings if given, and
    ``rates``, a list of rates with a string key, integer threads (>= 0) and stages (>= 1), and
    finite non-negative seconds (``_RATE_FIELDS``)."""
    if not isinstance(m, dict):
        raise UserError(f"{where} is {type(m).__name__}, not an object")
    for name in ("cpu", "isa", "machine", "date", "command"):
        if name in m and not isinstance(m[name], str):
            raise UserError(f"{where}: {name!r} must be a string, got {m[name]!r}")
    if not isinstance(m.get("rates"), list):
        raise UserError(f"{where} has no list of rates")
    for j, r in enumerate(m["rates"]):
        at = f"{where}, rate {j}"
        if not isinstance(r, dict):
            raise UserError(f"{at} is {type(r).__name__}, not an object")
        for name, (types, required) in _RATE_FIELDS.items():
            if name not in r:
                if required:
                    raise UserError(f"{at} has no {name!r}")
                continue
            v = r[name]
            if isinstance(v, bool) or not isinstance(v, types):
                raise UserError(f"{at}: {name!r} is {v!r}")
            low = 1 if name == "stages" else 0
            if not isinstance(v, str) and not (finite_number(v) and v >= low):
                raise UserError(f"{at}: {name!r} is {str(v)[:40]}")


def same_machine(m: dict, cpu: str, isa: str) -> bool:
    """A table or stage record of this machine: its CPU model and instruction set (one recorded
    without an instruction set, older, matches on the model alone).  "AMD EPYC" names both a Zen 4
    with AVX-512 and an AVX2-only one, ~2x apart, whose rates must not pool."""
    return m.get("cpu") == cpu and m.get("isa", isa) == isa


def load_reference(path: Path = REFERENCE, cpu: str | None = None, isa: str | None = None) -> dict:
    """The shipped reference rates for this machine: those of its CPU model and instruction set,
    else of a machine with its instruction set, else of its CPU model, else of any (machines differ
    up to ~2x, and the instruction set more than the name: the AVX2-only AMD EPYC ran the stages
    ~2x slower than the AVX-512 Intel Xeon, and shares its name with a Zen 4 with AVX-512); a key
    the chosen machine never measured is taken from the next one, each rate marked with the CPU
    that measured it.  A malformed table raises ``ValueError`` naming the file."""
    if not path.exists():
        return {"cpu": "?", "rates": []}
    try:
        machines = reference_machines(read_json(path))
    except (OSError, ValueError) as e:
        raise UserError(f"{path}: not a rates table ({e})") from None
    cpu = cpu_model() if cpu is None else cpu
    isa = instruction_set() if isa is None else isa
    machines = sorted(
        machines,
        key=lambda m: (
            not same_machine(m, cpu, isa),  # this machine's (one without a set, older, too)
            m.get("isa") != isa,  # the exact match before the table without a set
            m.get("cpu") != cpu,
        ),
    )
    rates, keys = [], set()
    for m in machines:
        mine = [{**r, "cpu": m.get("cpu", "?")} for r in m["rates"] if r["key"] not in keys]
        keys |= {r["key"] for r in mine}
        rates += mine
    return {"cpu": machines[0].get("cpu", "?"), "rates": rates}


def find_rate(key: str, threads: int, table: dict, cpu: str, reference: dict) -> Rate | None:
    """The rate of ``key`` at ``threads`` torch threads (see the module's order of sources).
    Collections, derivations and filters do not depend on torch's threads: any count matches."""
    ref_cpu = reference.get("cpu", "?")
    sources = (
        ("here", {k: v for k, v in table.items() if k[1] == cpu}),
        ("reference", {(r["key"], r.get("cpu", ref_cpu), r["threads"]): r
                       for r in reference["rates"]}),
    )  # fmt: skip
    for source, rows in sources:
        found = [(t, v) for (k, _, t), v in rows.items() if k == key]
        if not found:
            continue
        measured_on = next(c for (k, c, _) in rows if k == key)
        if source == "reference" and measured_on != ref_cpu:
            source = f"reference, {measured_on}"  # a fallback machine's rate: said
        same = [v for t, v in found if t == threads or not _threaded(key)]
        if same:
            v = same[0]
            return Rate(v["seconds_per_unit"], v.get("overhead_s", 0.0), source, v["stages"])
        # another thread count: the nearest measured one, converted
        t, v = min(found, key=lambda tv: (abs(tv[0] - threads), tv[0]))
        factor = THREAD_FACTOR if threads < t else 1 / THREAD_FACTOR
        basis = f"{source}, {t}-thread rate x {factor:.2f}"
        spu = v["seconds_per_unit"] * factor
        return Rate(spu, v.get("overhead_s", 0.0), basis, v["stages"])
    return None


def twins(env: str) -> list[str]:
    """The other registered envs whose stages cost the same per unit as ``env``'s: the same
    declared ``cost_class`` (the Meta-World ML1 tasks: one model size, one simulated arm; a task's
    own contacts make its steps cost a few percent more or less) and, as a guard, the same spaces,
    horizon and default context; in registry order.  Gridworld variants declare none: their
    dynamics differ (Dark Key-to-Door's planned steps cost 1.4x Darkroom-Permuted's), and each
    has its own measured rates."""
    spec = get_spec(env)

    def shape(s) -> tuple:
        return (s.cost_class, describe_space(s.state_space), describe_space(s.action_space),
                s.horizon, s.context_length)  # fmt: skip

    if spec.cost_class is None:
        return []
    return [e for e in list_env_ids() if e != env and shape(get_spec(e)) == shape(spec)]


def find_twin_rate(key: str, threads: int, table: dict, cpu: str, reference: dict) -> Rate | None:
    """``find_rate`` of the same kind of stage on a twin env (``twins``), when the key's own env
    has none: its basis names the env it was measured on."""
    try:
        parsed = RateKey.parse(key)
    except ValueError:
        return None
    if parsed.env is None:  # a derivation's or filter's key names no env
        return None
    try:
        others = twins(parsed.env)
    except KeyError:  # a key of an env no longer registered
        return None
    for other in others:
        rate = find_rate(str(parsed.on(other)), threads, table, cpu, reference)
        if rate is not None:
            return Rate(rate.seconds_per_unit, rate.overhead_s,
                        f"{rate.basis}, measured on {other}", rate.stages)  # fmt: skip
    return None


def _other_contexts(key: str, known: set[str]) -> str:
    """What a rate-less key's own or twin envs were measured at instead, in words ("" if none):
    a rate holds for one model context, so another context's is not used."""
    try:
        parsed = RateKey.parse(key)
        envs = {parsed.env, *twins(parsed.env)} if parsed.env is not None else set()
    except (ValueError, KeyError):  # not a key, or an env no longer registered
        return ""
    if parsed.kind not in ("train", "evaluate") or not envs:
        return ""
    found = set()
    for k in known:
        try:
            other = RateKey.parse(k)
        except ValueError:
            continue
        if (other.kind, other.fields) != (parsed.kind, parsed.fields) or other.env not in envs:
            continue
        if other.context != parsed.context:
            c = other.context
            found.add("the env's default context" if c is None else f"context {c}")
    if not found:
        return ""
    return f" (measured only at {' and '.join(sorted(found))}: a rate holds for one context)"


def _threaded(key: str) -> bool:
    return key.startswith(("train", "evaluate"))


def estimate(
    stages: Sequence[Stage], work: str | Path, jobs: int = 1, reference: dict | None = None
) -> dict:
    """Per stage: cached or not, its estimated seconds and the rate's basis; and the totals."""
    cpu, isa, threads_here = cpu_model(), instruction_set(), torch.get_num_threads()
    table = rate_table([r for r in measured_stages(work) if same_machine(r, cpu, isa)])
    reference = load_reference() if reference is None else reference
    rows, missing = [], []
    known = {k for k, _, _ in table} | {r["key"] for r in reference["rates"]}  # for the reasons
    for s in stages:
        row = {"kind": s.kind, "label": s.label, "cached": s.done(Path(work)), "seconds": None}
        if not row["cached"] and s.cost is not None:
            threads = 1 if jobs > 1 and _threaded(s.cost.key) else threads_here
            rate = find_rate(s.cost.key, threads, table, cpu, reference) or find_twin_rate(
                s.cost.key, threads, table, cpu, reference
            )
            if rate is None:
                row["basis"] = f"no measured rate for {s.cost.key}" + _other_contexts(
                    s.cost.key, known
                )
                missing.append(s.cost.key)
            else:
                row["seconds"] = rate.seconds(s.cost.units)
                if jobs > 1 and s.kind not in IN_PROCESS:
                    row["seconds"] += CHILD_START_S
                row["basis"] = f"{rate.basis}, {plural(rate.stages, 'stage')}"
        rows.append(row)
    durations = {s.hash: (r["seconds"] or 0.0) for s, r in zip(stages, rows, strict=True)}
    done = {s.hash for s, r in zip(stages, rows, strict=True) if r["cached"]}
    return {
        "cpu": cpu,
        "cores": os.cpu_count() or 1,
        "reference_cpu": reference.get("cpu", "?"),
        "jobs": jobs,
        "unknown": sum(r["seconds"] is None and not r["cached"] for r in rows),
        "stages": rows,
        "to_run": sum(not r["cached"] for r in rows),
        "wall_s": schedule(stages, durations, done, jobs),
        "stage_s": sum(durations.values()),
        "missing": sorted(set(missing)),
    }


def schedule(
    stages: Sequence[Stage], seconds: dict[str, float], done: set[str], jobs: int
) -> float:
    """Wall time of ``parallel.run_stages`` (or the sequential runner) on these durations: stages
    start in ``start_order`` (collections first) once their inputs are done, at most ``jobs`` at
    once, collections alone, derivations and filters in the scheduling process (nothing starts
    while they run)."""
    if jobs == 1:
        return sum(seconds[s.hash] for s in stages if s.hash not in done)
    now, finished = 0.0, set(done)
    pending = [s for s in start_order(stages) if s.hash not in done]
    running: list[tuple[float, str]] = []  # (end, hash) of the children
    while pending or running:
        for s in list(pending):
            if any(i.hash not in finished for i in s.inputs):
                continue
            if not can_start(s, len(running), jobs):
                break
            pending.remove(s)
            if s.kind in IN_PROCESS:
                now += seconds[s.hash]  # blocks the scheduler
                finished.add(s.hash)
                continue
            heapq.heappush(running, (now + seconds[s.hash], s.hash))
        if not running:
            if pending:  # inputs outside the plan: nothing more can start
                break
            continue
        end, h = heapq.heappop(running)
        now = max(now, end)
        finished.add(h)
    return now


def render(est: dict, header: str) -> str:
    lines = [header, ""]
    n = len(est["stages"])
    width = len(f"[{n}/{n}]")
    for i, r in enumerate(est["stages"], 1):
        if r["cached"]:
            what = "cached"
        elif r["seconds"] is None:
            what = f"to run, ? ({r['basis']})"
        else:
            what = f"to run, ~{duration(r['seconds'])} ({r['basis']})"
        lines.append(f"{f'[{i}/{n}]':<{width}} {r['kind']:<8} {r['label']}: {what}")
    lines += [
        "",
        f"Rates: 'here' = stages finished on this machine ({est['cpu']}) under the work folder; "
        f"'reference' = lhf_hf/reproduce/rates.json ({est['reference_cpu']}); 'reference, CPU' = "
        "a rate that table lacks, taken from the machine named (CPU models differ up to ~2x: "
        "an AVX2-only AMD EPYC ran ~2x slower than the AVX-512 Intel Xeon); 'N-thread rate x F' "
        f"= measured at another torch thread count, converted ({THREAD_FACTOR:.2f}x from 2 threads "
        "to 1); 'measured on ENV' = a twin env's rate, this one's never measured (same cost class, "
        "EnvSpec.cost_class).",
    ]
    if est["jobs"] > est["cores"]:
        lines.append(
            f"--jobs {est['jobs']} exceeds the {est['cores']} cores: the stages would share cores, "
            "which this estimate does not model (it assumes a core per job)"
        )
    total = f"~{duration(est['wall_s'])} wall with --jobs {est['jobs']}"
    if est["jobs"] > 1:
        total += f" ({duration(est['stage_s'])} of stage time)"
    if est["missing"]:
        timed = est["to_run"] - est["unknown"]
        lines.append(
            f"{est['to_run']} of {plural(n, 'stage')} to run: at least {total}, for the {timed} "
            f"with a rate; unknown for the other {est['unknown']} (marked '?', "
            f"{plural(len(est['missing']), 'kind')} of stage never "
            "measured: a finished stage records its rate, so running the same env, objective and "
            "model preset once for a few steps (the specs in benchmarks/calibration/: "
            "gridworlds.yaml, planning.yaml, planning-key-to-door.yaml, lightweight.yaml, "
            "metaworld.yaml, sac-collection.yaml) completes the estimate)"
        )
    else:
        lines.append(f"{est['to_run']} of {plural(n, 'stage')} to run: {total}")
    return "\n".join(lines)


def plural(n: int, word: str) -> str:
    """``1 stage``, ``2 stages``."""
    return f"{n} {word}{'s' * (n != 1)}"


def duration(seconds: float) -> str:
    s = int(round(seconds))
    if s < 90:
        return f"{s} s"
    if round(s / 60, 1) < 90:
        return f"{s / 60:.1f} min"
    if s < 2 * 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:,.1f} days"  # the paper preset on 2 cores: thousands of hours
