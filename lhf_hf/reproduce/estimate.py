"""``lhf reproduce --estimate`` (docs/reproduce.md, ``estimate.py``): what would run, what is cached,
and about how long.  A stage's ``Cost`` is units of work of a key (kind, env and what its rate
depends on); its time is the units x a seconds-per-unit rate from, in order: the finished stages of
the key in this work folder on this CPU model, the shipped ``rates.json``, a twin env's key.
"""

from __future__ import annotations

from pathlib import Path

from lhf_hf.collection.backend_verdict import cpu_model
from lhf_hf.configs import CollectConfig, EvalConfig, TrainConfig
from lhf_hf.envs import get_spec, list_env_ids
from lhf_hf.evaluation.evaluate import resolve_tasks
from lhf_hf.training.model_config import model_config_for, sequence_length
from lhf_hf.utils.io import read_json

from .parallel import IN_PROCESS
from .stages import DONE_FILE, Cost, Stage, done_record

REFERENCE = Path(__file__).resolve().parent / "rates.json"


def _key(kind: str, env: str, fields: tuple, train: TrainConfig | None = None) -> str:
    context = train and (train.context_length or get_spec(env).context_length)
    tag = [f"ctx{context}"] if context and context != get_spec(env).context_length else []
    return "|".join([kind, env, *fields, *tag])


def collect_cost(cfg: CollectConfig) -> Cost:
    key = _key("collect", cfg.env_id, (cfg.collector, cfg.algo))
    return Cost(key, float(len(cfg.tasks) * cfg.histories * cfg.steps))


def train_cost(env: str, cfg: TrainConfig) -> Cost:
    config = model_config_for(get_spec(env), cfg, has_optimal=True)
    tokens = sequence_length(cfg, config) * config.tokens_per_transition
    key = _key("train", env, (cfg.objective, cfg.preset, cfg.attention), cfg)
    return Cost(key, float(cfg.max_steps * cfg.batch_size * tokens))


def eval_cost(env: str, objective: str, train: TrainConfig, cfg: EvalConfig, split: int) -> Cost:
    """Env-steps; with planning on discrete actions only those after the context is full (a
    beam-search step costs tens of model-free ones; Meta-World's greedy search about one)."""
    spec = get_spec(env)
    steps = cfg.episodes * spec.horizon
    if cfg.plan and spec.is_discrete:
        steps = max(steps - (train.context_length or spec.context_length), 0)
    context = (
        cfg.context if cfg.context != "auto" else "cache" if train.attention == "band" else "window"
    )
    fields = (objective, train.preset, "plan" if cfg.plan else "no plan", context)
    tasks = len(resolve_tasks(env, cfg.tasks, split))
    return Cost(_key("evaluate", env, fields, train), float(steps * tasks * cfg.rollouts))


def measured(work: str | Path, cpu: str | None = None) -> dict[str, dict]:
    """``{key: {"seconds", "units", "stages"}}`` of the finished stages under ``work`` that ran
    whole (not resumed) on this CPU model."""
    cpu = cpu or cpu_model()
    out: dict[str, dict] = {}
    for path in sorted(Path(work).glob(f"*/*/{DONE_FILE}")):
        rec = done_record(path.parent)
        cost = (rec or {}).get("cost")
        if not isinstance(cost, dict) or rec.get("cpu") != cpu or rec.get("resumed"):
            continue
        if not isinstance(cost.get("units"), int | float) or cost["units"] <= 0:
            continue
        m = out.setdefault(str(cost["key"]), {"seconds": 0.0, "units": 0.0, "stages": 0})
        m["seconds"] += rec["wall_s"]
        m["units"] += cost["units"]
        m["stages"] += 1
    return out


def reference_rates(path: Path = REFERENCE, cpu: str | None = None) -> dict[str, dict]:
    """``{key: rate}`` of ``rates.json``: this CPU model's table first, the others for what it
    lacks; each rate names its ``cpu``."""
    cpu = cpu or cpu_model()
    machines = read_json(path)["machines"] if path.exists() else []
    rates: dict[str, dict] = {}
    for m in sorted(machines, key=lambda m: m.get("cpu") != cpu):
        for r in m["rates"]:
            rates.setdefault(r["key"], {**r, "cpu": m.get("cpu", "?")})
    return rates


def twin_keys(key: str) -> list[tuple[str, str]]:
    """``[(key on a twin env, twin)]``: envs of the same declared ``cost_class``."""
    kind, *parts = key.split("|")
    try:
        env, rest, cls = parts[0], parts[1:], get_spec(parts[0]).cost_class
    except (IndexError, KeyError):  # a derivation's or filter's key names no env
        return []
    twins = [e for e in list_env_ids() if e != env and cls and get_spec(e).cost_class == cls]
    return [("|".join([kind, e, *rest]), e) for e in twins]


def stage_seconds(cost: Cost, here: dict, reference: dict) -> tuple[float | None, str]:
    """The seconds ``cost`` takes and where the rate comes from (None: no rate)."""
    if cost.key in here:
        m = here[cost.key]
        return m["seconds"] / m["units"] * cost.units, f"here, {m['stages']} stage(s)"
    for key, twin in [(cost.key, None), *twin_keys(cost.key)]:
        if key in reference:
            r = reference[key]
            basis = f"reference, {r['cpu']}" + (f", measured on {twin}" if twin else "")
            return r.get("overhead_s", 0.0) + r["seconds_per_unit"] * cost.units, basis
    return None, f"no measured rate for {cost.key}"


def estimate(stages: list[Stage], work: str | Path, jobs: int = 1, reference=None) -> dict:
    """Per stage: cached or not, its seconds and their basis; the totals.  With ``jobs > 1`` the
    wall time is the in-process stages one after the other plus the rest spread over the jobs."""
    here = measured(work)
    reference = reference_rates() if reference is None else reference
    rows, missing = [], set()
    for s in stages:
        row = {"kind": s.kind, "label": s.label, "cached": s.done(Path(work)), "seconds": None}
        if not row["cached"] and s.cost is not None:
            row["seconds"], row["basis"] = stage_seconds(s.cost, here, reference)
            if row["seconds"] is None:
                missing.add(s.cost.key)
        rows.append(row)
    timed = [r for r in rows if r["seconds"] is not None]
    alone = sum(r["seconds"] for r in timed if r["kind"] in IN_PROCESS)
    rest = [r["seconds"] for r in timed if r["kind"] not in IN_PROCESS]
    return {
        "jobs": jobs,
        "stages": rows,
        "to_run": sum(not r["cached"] for r in rows),
        "missing": sorted(missing),
        "stage_s": alone + sum(rest),
        "wall_s": alone + (max(sum(rest) / jobs, max(rest)) if rest else 0.0),
    }


def render(est: dict, header: str) -> str:
    n = len(est["stages"])
    lines = [header, ""]
    for i, r in enumerate(est["stages"], 1):
        time = "?" if r["seconds"] is None else f"~{duration(r['seconds'])}"
        what = "cached" if r["cached"] else f"to run, {time} ({r.get('basis', 'no cost')})"
        lines.append(f"[{i}/{n}] {r['kind']:<8} {r['label']}: {what}")
    total = f"~{duration(est['wall_s'])} wall with --jobs {est['jobs']}"
    total += f" ({duration(est['stage_s'])} of stage time)" if est["jobs"] > 1 else ""
    lower = "at least " if est["missing"] else ""
    lines += ["", f"{est['to_run']} of {n} stage(s) to run: {lower}{total}"]
    if est["missing"]:
        lines.append(
            f"{len(est['missing'])} kind(s) of stage never measured (marked '?'): a finished stage "
            "records its rate, so a short run of the same kind (benchmarks/calibration/) completes it"
        )
    return "\n".join(lines)


def duration(seconds: float) -> str:
    s = round(seconds)
    if s < 90:
        return f"{s} s"
    if round(s / 60, 1) < 90:  # never "90.0 min"
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.1f} h" if s < 2 * 86400 else f"{s / 86400:,.1f} days"
