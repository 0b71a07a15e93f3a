"""``report.md`` of a reproduction: our E beside the paper's, end-of-curve returns, curves, configs."""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import yaml

from .experiment import Experiment, shadows_shipped

#: A sweep's figure per env: every value's LHF curves beside the baseline, one panel per backbone.
SWEEP_FIGURE = "sweep.png"


def verdict(
    e: float | None,
    e_std: float | None,
    ci: tuple | list | None = None,
    diff_ci: tuple | list | None = None,
) -> str:
    """Honest reading of one cell. With 2+ paired runs the test is the paired t-test on the runs'
    return differences (LHF - baseline, same seed and split): an effect counts only when their
    mean's 95 % confidence interval (``diff_ci``) excludes 0. Tables made before the differences
    were recorded fall back to the 95 % interval of the mean per-run E (``ci``), and older ones
    to E against its run-to-run std. The verdict says whether LHF raised the return (the effect's
    direction); E and its interval say by how much. Disclosed: the test was moved from E's interval
    to the differences after E's interval spanned 0 on the main job's runs whose three differences
    were all +2.7 .. +4.4 (docs/reproduce.md)."""
    if _finite_pair(diff_ci):
        return _judge(diff_ci, "the paired return difference's 95% CI spans 0")
    if e is None or not np.isfinite(e):
        return "undefined (baseline return 0)"
    if _finite_pair(ci):
        return _judge(ci, "the 95% CI spans 0")
    if e_std is None:
        # one paired run (or baseline and LHF runs that pair only once) has no spread to judge
        # against: its sign is reported, never a verdict
        side = "higher" if e > 0 else "lower" if e < 0 else "level"
        return f"not judged (1 paired run, no error bar): the return is {side} with LHF"
    if e - e_std > 0:
        return "helps"
    if e + e_std < 0:
        return "hurts"
    return "no clear effect (|E| within its std)"


def _finite_pair(interval) -> bool:
    return interval is not None and len(interval) == 2 and all(np.isfinite(x) for x in interval)


def _judge(interval, spans: str) -> str:
    """An interval of the effect: above 0 helps, below 0 hurts, otherwise no clear effect."""
    if interval[0] > 0:
        return "helps"
    if interval[1] < 0:
        return "hurts"
    return f"no clear effect ({spans})"


def default_out(name: str, preset: str, narrowed_to=None) -> str:
    """``results/NAME-PRESET``, with the backbones appended when the grid is narrowed."""
    tail = "-" + "-".join(narrowed_to) if narrowed_to else ""
    return f"results/{name}-{preset}{tail}"


def command_line(
    name: str,
    preset: str,
    runs: int,
    narrowed_to=None,
    out: str | None = None,
    spec: str | None = None,
) -> str:
    """The ``lhf reproduce`` call that makes a table (``narrowed_to``: its objectives when only
    some of the spec's were run; ``out``: its folder, written only when not the default one;
    ``spec``: the yaml path of a spec that is not shipped, which ``name``, its stem, would not
    find; one named like a shipped spec has no default folder, so its ``out`` is always written)."""
    tail = f" --objectives {' '.join(narrowed_to)}" if narrowed_to else ""
    default = Path(default_out(name, preset, narrowed_to))
    if out is not None and (shadows_shipped(name, spec) or Path(out) != default):
        tail += f" --out {shlex.quote(str(out))}"
    return f"lhf reproduce {shlex.quote(spec or name)} --preset {preset} --runs {runs}{tail}"


def _objective(backbone: str) -> str:
    return backbone.split()[0].lower()


def _pct(x: float | None) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{100 * x:+.1f}"


def _columns(exp: Experiment) -> list[str]:
    """The E table's backbone columns: one per objective, DICP once per planning mode."""
    cols = []
    for o in exp.objectives:
        modes = exp.dicp_plan_modes() if o == "dicp" else (False,)
        cols += [o.upper() + (" + plan" if plan else "") for plan in modes]
    return cols


def _selection_lines(selections: list[dict]) -> list[str]:
    """What LHF kept, per run: the histories it kept and rejected and their mean returns (each
    history's mean over its episodes), the question being whether the selection is cleaner data."""
    if not selections:
        return []

    def num(x) -> str:
        return "-" if x is None else f"{x:.2f}"

    lines = [
        "",
        "## What LHF kept",
        "",
        "Per run: histories kept (at least once) and rejected, and the mean return of each group "
        "(a history's mean over its episodes); the last column weighs the kept ones by how often "
        "the resampling drew them, i.e. the data the LHF model trained on.",
        "",
        "| env | arm | run | kept / rejected | source | kept | rejected | resampled |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in selections:
        lines.append(
            f"| {s['env_id']} | {s['arm']} | {s['run']} | {s['selected_unique']} / {s['rejected']} "
            f"| {num(s['mean_return_source'])} | {num(s['mean_return_selected_unique'])} "
            f"| {num(s['mean_return_rejected'])} | {num(s['mean_return_selection'])} |"
        )
    return lines


def _other_data_lines(other: list[dict]) -> list[str]:
    """A warning: models trained on another draw of a collection than the one the selection
    summary above describes (``reproduce._other_data``)."""
    if not other:
        return []
    machines = sorted(
        {
            "{cpu}, {isa}".format(**{"cpu": "?", "isa": "?", **(o.get("here_machine") or {})})
            for o in other
        }
    )
    lines = [
        "",
        f"**Warning**: {len(other)} evaluation(s) are of models trained on other data than the "
        "collection in this work folder, made from the same config (typically imported "
        "evaluations: a collection made again on a CPU of another instruction set is another "
        "draw, docs/histories.md). The selection summary above describes the collection here "
        f"({', '.join(machines)}), not the data these models trained on:",
        "",
    ]
    lines += [
        f"- {o['stage']}: trained on {o['trained_on'][:12]}, here {o['here'][:12]}" for o in other
    ]
    return lines


def render_report(exp: Experiment, cells: list[dict], summary: dict, out: Path) -> str:
    cols = _columns(exp)
    lines = [
        f"# {exp.title}",
        "",
        f"`{command_line(exp.name, exp.preset, exp.runs, exp.objectives if exp.narrowed else None, str(out), exp.spec)}`: "
        f"{exp.runs} run(s); run r uses seed r and train/test split r (a different set of unseen "
        f"tasks per run). Paper: {exp.paper_table or '-'}.",
        "",
        f"**Budget** ({exp.preset}): {exp.budget or '-'}",
        "",
        "## Relative enhancement E (%) of LHF over each backbone",
        "",
        "E = (mean return over the whole test curve with LHF - without) / without, the returns "
        "averaged over runs; ± is the std of the per-run E over paired runs (same seed and split). "
        "The verdicts below give the 95% confidence interval of the mean per-run E (Student t) and "
        "judge on the paired t-test of the runs' return differences (LHF - baseline): an effect "
        "counts when that difference's 95% interval excludes 0 (a per-run E divides by its run's "
        "baseline return, so one weak baseline widens E's interval whatever the differences are). "
        "Paper values in parentheses.",
    ]
    if exp.dicp_plan_modes() == (False, True):
        gated = exp.evaluate.get("plan_gate", "always") != "always"
        lines += [
            "",
            "DICP is evaluated from the same checkpoints without planning (`DICP`) and with the "
            + (
                "paper's beam search, gated on an observed reward (`DICP + plan`: a task is "
                "planned for only while its context holds a reward, else it acts on a policy "
                "sample; a departure from the reference, docs/evaluation.md)"
                if gated
                else "paper's planning (`DICP + plan`)"
            )
            + "; the paper's DICP values are with planning.",
        ]
    lines += [
        "",
        "| env | " + " | ".join(cols) + " |",
        "|---|" + "---|" * len(cols),
    ]
    per_col: dict[str, list[float]] = {c: [] for c in cols}
    verdicts = []
    for cell in cells:
        rows = {r["backbone"]: r for r in cell["rows"]}
        label = cell["env_id"] + ("" if cell["arm"] == "lhf" else f" ({cell['arm']})")
        entries = []
        for c in cols:
            r = rows.get(c)
            paper = (exp.paper.get(cell["env_id"]) or {}).get(_objective(c))
            paper_s = f" ({paper:+.1f})" if paper is not None else ""
            if r is None:
                entries.append("-" + paper_s)
                continue
            std = f" ± {100 * r['E_std']:.1f}" if r["E_std"] is not None else ""
            entries.append(f"{_pct(r['E'])}{std}{paper_s}")
            if r["E"] is not None:  # undefined where the baseline returned 0
                per_col[c].append(r["E"])
            verdicts.append((label, r))
        lines.append(f"| {label} | " + " | ".join(entries) + " |")
    avg = []
    for c in cols:
        paper = [(exp.paper.get(e) or {}).get(_objective(c)) for e in exp.envs]
        paper = [p for p in paper if p is not None]
        paper_s = f" ({np.mean(paper):+.1f})" if paper and len(exp.envs) > 1 else ""
        avg.append((_pct(float(np.mean(per_col[c]))) if per_col[c] else "-") + paper_s)
    if len(cells) > 1:
        lines.append("| average | " + " | ".join(avg) + " |")
    lines += ["", "## Where LHF helps, and where it does not", ""]
    for label, r in verdicts:
        ci, diff_ci = r.get("E_ci95"), r.get("diff_ci95")
        facts = [f"95% CI of the per-run E: {_pct(ci[0])} .. {_pct(ci[1])}"] if ci else []
        if diff_ci:
            facts.append(
                f"paired return difference {r['diff']:+.2f}, 95% CI {diff_ci[0]:+.2f} .. {diff_ci[1]:+.2f}"
            )
        interval = f" ({'; '.join(facts)})" if facts else ""
        judged = verdict(r["E"], r["E_std"], ci, diff_ci)
        lines.append(f"- {label}, {r['backbone']}: E {_pct(r['E'])}%{interval} -> {judged}")
    lines += [
        "",
        "## Absolute returns",
        "",
        "Mean over runs of the whole-curve mean and of the last 10% of the episodes (end of the "
        "curve). The paper publishes no returns in numbers (only E in its tables and the curves "
        "of its figures), so there is none to set beside these.",
        "",
        "| env | backbone | baseline mean | LHF mean | baseline end | LHF end | runs |",
        "|---|---|---|---|---|---|---|",
    ]
    for cell in cells:
        label = cell["env_id"] + ("" if cell["arm"] == "lhf" else f" ({cell['arm']})")
        for r in cell["rows"]:
            lines.append(
                f"| {label} | {r['backbone']} | {r['baseline_mean']:.2f} ± {r['baseline_std']:.2f} | "
                f"{r['lhf_mean']:.2f} ± {r['lhf_std']:.2f} | {r['baseline_final']:.2f} | "
                f"{r['lhf_final']:.2f} | {r['runs_baseline']} |"
            )
    lines += _selection_lines(summary.get("selections") or [])
    lines += _other_data_lines(summary.get("other_data") or [])
    lines += ["", "## Learning curves on the unseen tasks", ""]
    for env in dict.fromkeys(cell["env_id"] for cell in cells):  # a sweep's figure first
        if (out / env / SWEEP_FIGURE).exists():
            lines += [f"![{env}, every swept value]({env}/{SWEEP_FIGURE})", ""]
    for cell in cells:
        rel = Path(cell["env_id"]) / cell["arm"] / "compare.png"
        if (out / rel).exists():
            lines.append(f"![{cell['env_id']} {cell['arm']}]({rel.as_posix()})")
            lines.append("")
    cached = sum(1 for s in summary["stages"] if s["cached"])
    ran = sum(s.get("wall_s", 0) for s in summary["stages"] if not s["cached"])
    lines += [
        "## Provenance",
        "",
        f"{len(summary['stages'])} stages ({cached} from cache"
        + (
            f"; {summary['left_out']} left out: not done, but what reads them is"
            if summary.get("left_out")
            else ""
        )
        + f"), {ran:.0f} s of stage time in this call"
        f" ({summary.get('wall_s', 0):.0f} s wall, {summary.get('jobs', 1)} at once)"
        + (
            f"; all stages, whichever call ran them: {summary['stage_s'] / 3600:.2f} h of stage time"
            if "stage_s" in summary
            else ""
        )
        + f"; created {summary['created']}. Versions: "
        + ", ".join(f"{k} {v}" for k, v in summary["versions"].items())
        + ".",
        "",
        *_imported_lines(summary.get("imported") or []),
        "Exact configuration (`results.json` also lists every stage folder):",
        "",
        "```yaml",
        yaml.safe_dump(exp.to_dict(), sort_keys=False).rstrip(),
        "```",
        "",
    ]
    return "\n".join(lines)


def _imported_lines(imported: list[dict]) -> list[str]:
    """Which evaluations were made on another machine (``--import-stages``), one line per export."""
    if not imported:
        return []
    exports = {(i.get("from"), i.get("created")): i.get("versions") or {} for i in imported}
    lines = [f"{len(imported)} evaluation(s) were imported (`--import-stages`), made elsewhere:"]
    for (where, created), versions in sorted(exports.items(), key=lambda kv: str(kv[0])):
        names = ", ".join(f"{k} {x}" for k, x in versions.items())
        lines.append(f"- from `{where}`, exported {created}" + (f" ({names})" if names else ""))
    return [*lines, ""]
