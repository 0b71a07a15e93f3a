"""``compare``: baseline vs LHF evaluation runs -> the paper's relative enhancement E, a table, a figure.

Each evaluation folder is one run (one seed / split).  Per backbone (objective, with "+plan" when
planning was on) and per run, the learning curve is the mean return over the run's test tasks per
episode.  The paper's relative enhancement is

    E = (mean return over the whole curve with LHF - the same without) / the same without,

computed from the means over runs.  With paired runs (the same number on both sides, paired in
the given order: same seed and split): its +/- is the sample std over runs of E computed run by
run, its 95 % interval is of this E itself (the ratio of the two means: the delta method on the
paired run means, ``_ratio_interval``), and the verdict's test is the paired t-interval of the
return differences.  Every other +/- is a sample std over runs (n - 1).  E is flagged where the
baseline's return is near zero (below ``NEAR_ZERO`` of the env's mean optimal return, on the
envs that know it): a ratio on a small base says little (issue 55's independent arm, 0.45).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import stats

from lhf_hf.envs import get_spec
from lhf_hf.errors import NotFoundError, UserError
from lhf_hf.training.card import is_seen
from lhf_hf.utils.io import read_json, write_json_atomic, write_text_atomic
from lhf_hf.utils.outputs import changed_since_written, output_folder

from .evaluate import RESULTS_FILE
from .plots import plot_comparison


def load_results(path: str) -> dict:
    """An evaluation's results (its folder or its ``eval_results.json``), as ``compare`` reads
    them: unchanged since written (its folder's manifest), then ``read_results``."""
    p = Path(path)
    f = p / RESULTS_FILE if p.is_dir() else p
    if not f.exists():
        raise NotFoundError(f"{path}: no {RESULTS_FILE} (made by `lhf evaluate`)")
    if changed_since_written(f.parent, [f.name]):  # a hand-edited result is not a result
        raise UserError(
            f"{f} changed since `lhf evaluate` wrote it (its folder's manifest says "
            "otherwise): not compared; `lhf verify` shows what changed"
        )
    return read_results(f)


def read_results(f: Path) -> dict:
    """The results file ``f`` with the fields ``compare`` reads checked (``lhf verify`` checks
    the manifest itself, so a changed file is reported once)."""
    try:
        r = read_json(f)
    except ValueError as exc:
        raise UserError(f"{f}: not readable JSON ({exc})") from None
    # what compare reads, checked here so that a damaged file is named, not a KeyError
    problem = None
    if not isinstance(r, dict):
        problem = "not a JSON object"
    elif not isinstance(r.get("config"), dict):
        problem = "no 'config' object"
    elif not isinstance(r.get("objective"), str) or not isinstance(r.get("env_id"), str):
        problem = "no 'objective' / 'env_id'"
    elif not isinstance(r.get("mean_curve"), list) or not r["mean_curve"]:
        problem = "no 'mean_curve' list"
    elif not all(
        isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
        for x in r["mean_curve"]
    ):
        problem = "'mean_curve' holds a value that is not a finite number"
    else:
        rollouts = r["config"].get("rollouts", 1)
        if isinstance(rollouts, bool) or not isinstance(rollouts, int) or rollouts < 1:
            problem = f"config.rollouts must be an integer >= 1, got {rollouts!r}"
    if problem:
        raise UserError(f"{f}: {problem} (not an `lhf evaluate` result)")
    r["_file"] = str(f.resolve())  # the run's identity: a folder and its results file are one run
    return r


def backbone_of(r: dict) -> str:
    """The table row of a run: its objective, planning, and "seen tasks" when the model trained on
    some of the evaluated tasks (``lhf evaluate --allow-seen``), so such a row is never read as
    unseen-task ICRL."""
    return (
        r["objective"].upper()
        + _planning(r["config"], _beam_searched(r))
        + (" [seen tasks]" if is_seen(r) else "")
    )


def _beam_searched(r: dict) -> bool:
    """Whether the run's planner is the beam search (discrete actions), whose tie order
    (``plan_ties``) matters; Meta-World's greedy search has none."""
    return "env_id" not in r or get_spec(r["env_id"]).is_discrete


def _planning(config: dict, beam_search: bool = True) -> str:
    """`` + plan`` for the reference planner (every step once the context is full, the learned
    dynamics, actions in sampled order), with each departure named: a variant of ours is its own
    row, never merged into the reference's (issue 55)."""
    if not config.get("plan"):
        return ""
    how = [
        *(["gated"] if config.get("plan_gate", "always") != "always" else []),
        *(["true dynamics"] if config.get("plan_dynamics", "model") != "model" else []),
        # a record without the field predates it: its beam search took depth-0 ties in the
        # policy's argmax order (like ``plan_ties`` below, a variant of ours)
        *(
            ["argmax order"]
            if beam_search and config.get("plan_order", "argmax") != "sample"
            else []
        ),
        *(
            ["ties by policy"]
            if beam_search and config.get("plan_ties", "policy") != "index"
            else []
        ),
        *([f"reward p >= {t:g}"] if (t := config.get("plan_reward_threshold")) else []),
    ]
    return " + plan" + "".join(f", {h}" for h in how)


def _group(paths: list[str], side: str) -> dict[str, list[dict]]:
    if not paths:
        raise UserError(f"no {side} evaluation runs given")
    out: dict[str, list[dict]] = {}
    for p in paths:
        r = load_results(p)
        r["_path"] = str(p)
        out.setdefault(backbone_of(r), []).append(r)
    return out


def mean_curves(paths: list[str]) -> dict[str, np.ndarray]:
    """Each backbone's per-run mean learning curves, (runs, episodes), of the evaluations at
    ``paths`` in the given order (a sweep's figure draws several arms' curves on one panel)."""
    return {
        backbone: np.array([r["mean_curve"] for r in runs])
        for backbone, runs in _group(paths, "evaluation").items()
    }


def _protocol(r: dict) -> str:
    """The context protocol of a run: ``cache`` and ``recompute`` compute the same function (tested
    equal), ``window`` another one (the reference's re-encoded window)."""
    return "window" if r["config"].get("context") == "window" else "streaming"


def _tasks_key(r: dict) -> tuple:
    return (r.get("split_seed"), tuple(r.get("tasks") or ()))


# Evaluation settings that change what a backbone's curve measures (EvalConfig; the defaults are
# what results written before a setting existed ran with).  Rollouts change the spread of a run's
# curve, not its expectation, but a table's error bars must come from one protocol.
_SETTINGS = {"rollouts": 1}
_PLAN_SETTINGS = {"plan_gate": "always", "plan_dynamics": "model", "plan_order": "sample",
                  "plan_reward_threshold": None, "plan_ties": "policy"}  # fmt: skip


def _settings(r: dict) -> tuple:
    keys = {**_SETTINGS, **(_PLAN_SETTINGS if r["config"].get("plan") else {})}
    if not _beam_searched(r):
        keys.pop("plan_ties", None)  # the greedy search has no tie order
    return tuple((k, r["config"].get(k, default)) for k, default in keys.items())


def _check_comparable(runs: list[dict], base: dict, filt: dict) -> None:
    """Refuse runs that measure different things: another context protocol, other evaluation
    settings within a backbone (rollouts, the planner's gate, dynamics and order), or an LHF run
    whose split and task set are not those of its paired baseline run (E pairs runs in the given
    order)."""
    # one results file on both sides (or twice on one) would pair a run with itself: E = 0, which
    # reads as "no effect" although nothing was compared
    seen: dict[str, str] = {}
    for r in runs:
        f = r["_file"]
        if f in seen:
            raise UserError(
                f"{r['_path']} and {seen[f]} are the same evaluation run ({f}); each run "
                "may be given once, on one side"
            )
        seen[f] = r["_path"]
    protocols = {_protocol(r) for r in runs}
    if len(protocols) != 1:
        modes = sorted({f"{r['config'].get('context', 'cache')} ({r['_path']})" for r in runs})
        raise UserError(f"the runs use different context protocols: {modes}")
    for backbone in sorted(base):
        b, f = base[backbone], filt[backbone]
        settings: dict[tuple, list[str]] = {}
        for r in (*b, *f):
            settings.setdefault(_settings(r), []).append(r["_path"])
        if len(settings) > 1:
            # name only the settings that differ, and every run with each value
            first = next(iter(settings))
            keys = [k for i, (k, _) in enumerate(first) if len({key[i][1] for key in settings}) > 1]
            shown = "; ".join(
                f"{', '.join(f'{k}={v!r}' for k, v in key if k in keys)} ({', '.join(paths)})"
                for key, paths in settings.items()
            )
            raise UserError(f"{backbone} runs were evaluated with different settings: {shown}")
        if len(b) == len(f):
            for rb, rf in zip(b, f, strict=True):
                if _tasks_key(rb) != _tasks_key(rf):
                    raise UserError(
                        f"{backbone} runs paired in the given order differ in split or "
                        f"tasks: {rb['_path']} (split {rb.get('split_seed')}, tasks "
                        f"{rb.get('tasks')}) vs {rf['_path']} (split {rf.get('split_seed')}, tasks "
                        f"{rf.get('tasks')}); give the runs in the same order on both sides"
                    )
        elif {_tasks_key(r) for r in b} != {_tasks_key(r) for r in f}:
            raise UserError(
                f"{backbone} baseline and LHF runs are on different splits or task sets"
            )


def compare(
    baseline: list[str], lhf: list[str], out: str | Path | None = None, overwrite: bool = False
) -> dict:
    """E per backbone of the ``lhf`` runs over the ``baseline`` runs (module docstring); with
    ``out``, also ``compare.md``, ``compare.json`` and ``compare.png`` there (an existing
    comparison is replaced only with ``overwrite``)."""
    inputs = [*baseline, *lhf]
    if out is None:
        return _compare(baseline, lhf, None)
    with output_folder(
        out, "comparison", overwrite=overwrite, inputs=inputs, legacy=["compare.json"]
    ):
        return _compare(baseline, lhf, out)


#: E is flagged when the baseline's mean return is below this share of the env's mean optimal
#: return: a relative change of a near-zero return is mostly noise in its denominator.
NEAR_ZERO = 0.1


def _near_zero(env_id: str, baseline_mean: float) -> str | None:
    """E's note when the baseline's return is near zero for ``env_id``; None otherwise (or when the
    env has no known optimal return, as Meta-World)."""
    spec = get_spec(env_id)
    if spec.optimal_returns is None:
        return None
    scale = float(np.mean(spec.optimal_returns()))
    if baseline_mean >= NEAR_ZERO * scale:
        return None
    return (
        f"the baseline's return {baseline_mean:.2f} is near zero (below {NEAR_ZERO:.0%} of the "
        f"env's mean optimal return {scale:.1f}): E is a ratio on a small base"
    )


def _std(x: np.ndarray) -> float | None:
    """Sample std over runs (n - 1); None for one run (a spread is not measured by one)."""
    return float(x.std(ddof=1)) if len(x) > 1 else None


def _compare(baseline: list[str], lhf: list[str], out: str | Path | None) -> dict:
    base, filt = _group(baseline, "baseline"), _group(lhf, "--lhf")
    runs = [r for rs in (*base.values(), *filt.values()) for r in rs]
    envs = {r["env_id"] for r in runs}
    if len(envs) != 1:
        raise UserError(f"the runs are on different envs {sorted(envs)}")
    episodes = {len(r["mean_curve"]) for r in runs}
    if len(episodes) != 1:
        raise UserError(f"the runs have different numbers of episodes {sorted(episodes)}")
    if set(base) != set(filt):
        raise UserError(
            f"backbones differ between baseline {sorted(base)} and LHF {sorted(filt)} runs (a row "
            "is a backbone and how it was evaluated: a planner setting after '+ plan' is its own "
            "row; evaluate both sides with the same settings)"
        )
    _check_comparable(runs, base, filt)
    env_id = next(iter(envs))
    rows, curves = [], {}
    for backbone in sorted(base):
        b = np.array([r["mean_curve"] for r in base[backbone]])  # (runs, E)
        f = np.array([r["mean_curve"] for r in filt[backbone]])
        mb, mf = b.mean(1), f.mean(1)  # whole-curve mean per run
        # E divides by the baseline's return: with a baseline of 0 it is undefined (None in the
        # JSON, which stays valid JSON; NaN is not), and the paired difference still says which
        # arm returned more
        s = paired_statistics(mb, mf)
        e = s["E"]
        tail = max(1, b.shape[1] // 10)
        rows.append(
            {
                "backbone": backbone,
                "runs_baseline": len(mb),
                "runs_lhf": len(mf),
                "baseline_mean": float(mb.mean()),
                "baseline_std": _std(mb),
                "lhf_mean": float(mf.mean()),
                "lhf_std": _std(mf),
                "baseline_final": float(b[:, -tail:].mean()),
                "lhf_final": float(f[:, -tail:].mean()),
                "E": e,
                "E_note": "undefined: the baseline's mean return is 0"
                if e is None
                else _near_zero(env_id, float(mb.mean())),
                **{k: v for k, v in s.items() if k != "E"},
                "baseline_run_means": mb.tolist(),
                "lhf_run_means": mf.tolist(),
                "baseline_runs": [r["_path"] for r in base[backbone]],
                "lhf_runs": [r["_path"] for r in filt[backbone]],
            }
        )
        curves[backbone] = {"baseline": b, "lhf": f}
    table = markdown_table(rows, env_id)
    result = {"env_id": env_id, "episodes": episodes.pop(), "rows": rows, "table": table}
    if out is not None:
        out = Path(out)
        write_json_atomic(result, out / "compare.json")
        write_text_atomic(table + "\n", out / "compare.md")
        plot_comparison(
            curves, out / "compare.png", title=f"{env_id}: baseline (dashed) vs LHF (solid)"
        )
    return result


def paired_statistics(mb: np.ndarray, mf: np.ndarray) -> dict:
    """What a row says about E from the runs' whole-curve means, baseline ``mb`` and LHF ``mf``
    (runs,), paired by index (same seed and split): ``E`` (None where the baseline's mean is 0),
    ``E_std`` (the sample std of the per-run E), ``E_interval95`` (the 95% interval of the E
    printed, the delta method), ``diff`` / ``diff_ci95`` (the mean paired return difference and
    its Student-t interval: the verdict's test), ``diff_mde80`` / ``E_mde80`` (the minimum
    detectable difference and E).  Each None where it is undefined (fewer than 2 paired runs)."""
    mb, mf = np.asarray(mb, dtype=float), np.asarray(mf, dtype=float)
    e = float((mf.mean() - mb.mean()) / mb.mean()) if mb.mean() != 0 else None
    out = dict.fromkeys(("E_std", "E_interval95", "diff", "diff_ci95", "diff_mde80", "E_mde80"))
    out["E"] = e
    if not (len(mb) == len(mf) and len(mb) > 1):
        return out
    if np.all(mb != 0):
        out["E_std"] = float(np.std((mf - mb) / mb, ddof=1))  # per-run E (same seed and split)
    if e is not None:
        # 95% interval of the E printed (with 2 or 3 runs it is wide: t = 12.7 / 4.3, which is
        # the honest reading)
        out["E_interval95"] = _ratio_interval(mb, mf)
    # The verdict's test: the paired t-test on the runs' return differences. A per-run ratio
    # divides by that run's baseline return, so one weak baseline (0.6 against 1.9) makes E's
    # spread, and its interval, as wide as the effect however alike the differences are; with
    # positive baseline returns (the gridworlds' and Meta-World's are >= 0) the difference has
    # the sign of E.
    out["diff"] = float((mf - mb).mean())
    out["diff_ci95"] = _t_interval(mf - mb)
    out["diff_mde80"] = detectable_difference(mf - mb)
    out["E_mde80"] = None if e is None else out["diff_mde80"] / float(mb.mean())
    return out


def _ratio_interval(b: np.ndarray, f: np.ndarray) -> list[float]:
    """95% interval of E = mean(f) / mean(b) - 1 from paired run means ``b``, ``f`` (runs,): the
    delta method, Var(E) ~ (s_d^2 / B^2 + D^2 s_b^2 / B^4 - 2 D s_db / B^3) / n with d = f - b,
    D and B the means, sample (co)variances, and Student t with n - 1 degrees of freedom."""
    n, d = len(b), f - b
    mb, md = b.mean(), d.mean()
    cov = np.cov(np.stack([d, b]), ddof=1)  # [[s_d^2, s_db], [s_db, s_b^2]]
    var = (cov[0, 0] / mb**2 + md**2 * cov[1, 1] / mb**4 - 2 * md * cov[0, 1] / mb**3) / n
    half = stats.t.ppf(0.975, n - 1) * math.sqrt(max(var, 0.0))
    return [float(md / mb - half), float(md / mb + half)]


def detectable_difference(d: np.ndarray) -> float:
    """The smallest mean paired difference the verdict's test (two-sided, 5 %) detects with 80 %
    power at the spread of ``d`` (runs,): (t(0.975, n-1) + t(0.8, n-1)) x s_d / sqrt(n).  With
    the baseline's mean it is the minimum detectable E (``E_mde80``): a cell whose effect is below
    it needs more runs before its verdict means anything."""
    n = len(d)
    return float(
        (stats.t.ppf(0.975, n - 1) + stats.t.ppf(0.8, n - 1)) * d.std(ddof=1) / math.sqrt(n)
    )


def _t_interval(x: np.ndarray) -> list[float]:
    """95% confidence interval of the mean of ``x`` (runs,): Student t, n - 1 degrees of freedom."""
    half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))
    return [float(x.mean() - half), float(x.mean() + half)]


def _difference(r: dict) -> str:
    """The mean paired return difference (LHF - baseline) and its 95% interval, the verdict's
    test (``reproduce.report.verdict``); ``-`` without 2+ paired runs."""
    ci = r.get("diff_ci95")
    if r.get("diff") is None or not ci:
        return "-"
    return f"{r['diff']:+.2f} ({ci[0]:+.2f} .. {ci[1]:+.2f})"


def markdown_table(rows: list[dict], env_id: str) -> str:
    def pm(m, s):
        return f"{m:.2f}" + ("" if s is None else f" ± {s:.2f}")

    lines = [
        f"| {env_id} | baseline | LHF | E (%) | final baseline | final LHF | runs "
        "| paired difference (95% CI) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        e = (
            "undefined (baseline 0)"
            if r["E"] is None
            else f"{100 * r['E']:+.1f}"
            + (f" ± {100 * r['E_std']:.1f}" if r["E_std"] is not None else "")
            + (" (baseline near 0)" if r.get("E_note") else "")
        )
        lines.append(
            f"| {r['backbone']} | {pm(r['baseline_mean'], r['baseline_std'])} | {pm(r['lhf_mean'], r['lhf_std'])} "
            f"| {e} | {r['baseline_final']:.2f} | {r['lhf_final']:.2f} | {r['runs_baseline']}/{r['runs_lhf']} "
            f"| {_difference(r)} |"
        )
    return "\n".join(lines)
