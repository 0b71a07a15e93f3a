"""Which evaluation tasks a model was trained on: the guard that keeps "unseen" honest.

ICRL reports returns on tasks held out of pretraining (paper section 3, "unseen test
environments"); a return on a task the model trained on measures memory, not in-context learning.
``lhf train`` records the training data's task indices and split seed in the model's config
(``ICRLConfig.train_tasks`` / ``split_seed``, so every ``checkpoint-N`` carries them), and
``lhf evaluate`` asks ``seen_tasks`` before it rolls anything out.
"""

from __future__ import annotations

from lhf_hf.envs.registry import EnvSpec, split_part
from lhf_hf.errors import UserError


class SeenTasksError(UserError):
    """An evaluation asked for tasks the model trained on, without ``allow_seen``."""


def seen_tasks(spec: EnvSpec, config, tasks: list[int], split_seed: int) -> list[int] | None:
    """The tasks of ``tasks`` (under ``split_seed``) that ``config``'s model was trained on.

    None: the model does not record its training tasks, so no task can be called unseen.
    Gridworld task indices name the same task under every split seed; where the task content is
    drawn from the split seed (``spec.seeded_tasks``: Meta-World ML1's goals), a task is the one
    trained on only under the training split seed.
    """
    trained = getattr(config, "train_tasks", None)
    if trained is None:
        return None
    if spec.seeded_tasks and getattr(config, "split_seed", None) != split_seed:
        return []
    trained = set(trained)
    return sorted({t for t in tasks if t in trained})


def check_unseen(
    spec: EnvSpec, config, tasks: list[int], split_seed: int, allow_seen: bool, model: str
) -> list[int] | None:
    """``seen_tasks``, after refusing seen (or unknown) tasks unless ``allow_seen``."""
    seen = seen_tasks(spec, config, tasks, split_seed)
    if allow_seen:
        return seen
    if seen is None:
        raise SeenTasksError(
            f"{model} does not record the tasks it was trained on (a model not made by `lhf "
            "train`), so none of the evaluation tasks can be called unseen: pass --allow-seen "
            "to evaluate anyway (results are labelled 'seen tasks')"
        )
    if seen:
        shown = ", ".join(map(str, seen[:12])) + (" ..." if len(seen) > 12 else "")
        trained_split = getattr(config, "split_seed", None)
        if trained_split is not None and trained_split != split_seed:
            hint = (
                f"evaluate on the model's own split (split seed {trained_split}: leave out "
                "--split-seed and --tasks)"
            )
        elif set(seen) <= set(spec.validation_split(split_seed)[1]):
            # validation tasks are held out only of `--tasks fit` data
            hint = "for validation, train on data collected with --tasks fit"
        elif set(seen) <= set(spec.split(split_seed)[1]):
            hint = "train on data without them (collect --tasks train)"
        else:  # train (or fit) tasks: a model is never unseen on what it trained on
            hint = "evaluate on --tasks validation (a model trained on --tasks fit data) or test"

        raise SeenTasksError(
            f"{len(seen)} of the {len(tasks)} evaluation tasks of {spec.env_id} (split seed "
            f"{split_seed}) are in {model}'s training data ({shown}): results on them are not "
            f"in-context learning on unseen tasks. {hint[0].upper()}{hint[1:]}, or pass "
            "--allow-seen to report them as seen tasks"
        )
    return seen


def seen_label(seen: list[int] | None, num_tasks: int, part: str | None = None) -> str:
    """How an evaluation's task set is named in its plot, card and table: seen (a label starting
    with "seen tasks", ``lhf_hf.training.card.is_seen``) or not; tasks none of which the model
    trained on are "unseen tasks", or "validation tasks" where ``part`` (``EvalConfig.tasks``)
    names them so: held-out train tasks, where tuning is done, not the unseen test tasks results
    are reported on."""
    if seen is None:
        return "seen tasks (training tasks not recorded)"
    if not seen:
        return "validation tasks" if part == "validation" else "unseen tasks"
    if len(seen) == num_tasks:
        return "seen tasks"
    return f"seen tasks ({len(seen)} of {num_tasks})"


#: The goals a tuning tool (a sweep, a benchmark that picks a setting, a diagnosis) measures on:
#: validation goals, drawn from the train split; test goals are for reporting only.
TUNING_PARTS = ("validation", "test")


def tuning_tasks(env_id: str, part: str, split_seed: int, report_on_test: bool) -> list[int]:
    """The goals of ``part`` of split ``split_seed`` for a tuning tool.  ``test`` only with
    ``report_on_test``: a choice made by looking at test goals would be reported on the same goals
    (a model tuned this way trains on ``lhf collect --tasks fit`` data, so its validation goals
    stay unseen)."""
    if part not in TUNING_PARTS:
        raise UserError(f"--tasks {part!r}: a tuning tool measures on one of {TUNING_PARTS}")
    if part == "test" and not report_on_test:
        raise UserError(
            "--tasks test: test goals are for reporting only, never for choosing a setting; "
            "measure on --tasks validation (train on `lhf collect --tasks fit` data), or pass "
            "--report-on-test to report a choice already made"
        )
    return split_part(env_id, part, split_seed)
