"""Configuration of learning-history collection (docs/design.md section 3, paper appendix A.1)."""

from __future__ import annotations

import dataclasses
import os
import re
from dataclasses import dataclass, field
from typing import Literal, get_args

from lhf_hf import constants as C
from lhf_hf.envs import SPLIT_PARTS, get_spec, split_part
from lhf_hf.errors import OutOfRangeError, UserError

from .types import check_types

Protocol = Literal["paper", "independent", "noisy", "learners"]
Algo = Literal["ppo", "sac"]
Collector = Literal["sb3", "batched"]
#: what ``--collector`` takes: a collector, or ``auto`` (resolved per env and algorithm)
CollectorChoice = Literal["auto", "sb3", "batched"]
PpoBackend = Literal["auto", "kernel", "torch"]
PROTOCOLS: tuple[str, ...] = get_args(Protocol)
ALGOS: tuple[str, ...] = get_args(Algo)
COLLECTORS: tuple[str, ...] = get_args(Collector)
PPO_BACKENDS: tuple[str, ...] = get_args(PpoBackend)
#: transitions per batched chunk when tasks_per_chunk is not given (bounds memory at any scale)
CHUNK_TRANSITIONS = 50_000_000


@dataclass(frozen=True)
class PPOSettings:
    """SB3 PPO hyper-parameters that differ per env (paper Table "Key hyperparameters"); the rest
    are SB3 defaults (MlpPolicy, GAE 0.95, clip 0.2, ent 0, vf 0.5, max grad norm 0.5).

    n_steps: rollout length per environment copy between updates.
    batch_size: minibatch size.
    n_epochs: passes over each rollout.
    learning_rate: Adam step size.
    gamma: discount factor.
    """

    n_steps: int
    batch_size: int
    n_epochs: int
    learning_rate: float = 3e-4
    gamma: float = 0.99

    def __post_init__(self) -> None:
        check_types(self)
        for name in ("n_steps", "batch_size", "n_epochs"):
            if getattr(self, name) < 1:
                raise UserError(f"PPOSettings.{name} must be >= 1, got {getattr(self, name)!r}")
        if not 0 < self.learning_rate < 1:
            raise UserError(
                f"PPOSettings.learning_rate must be in (0, 1), got {self.learning_rate!r}"
            )
        if not 0 < self.gamma <= 1:
            raise UserError(f"PPOSettings.gamma must be in (0, 1], got {self.gamma!r}")


@dataclass(frozen=True)
class SACSettings:
    """SB3 SAC hyper-parameters for Meta-World (paper appendix A.1); the rest are SB3 defaults.

    batch_size: minibatch size.
    learning_rate: Adam step size of actor, critics and entropy coefficient.
    gamma: discount factor.
    learning_starts: environment steps (summed over copies) of uniform actions before updates.
    """

    batch_size: int = 128
    learning_rate: float = 3e-4
    gamma: float = 0.99
    learning_starts: int = 100

    def __post_init__(self) -> None:
        check_types(self)
        if self.batch_size < 1:
            raise UserError(f"SACSettings.batch_size must be >= 1, got {self.batch_size!r}")
        if not 0 < self.learning_rate < 1:
            raise UserError(
                f"SACSettings.learning_rate must be in (0, 1), got {self.learning_rate!r}"
            )


def _settings(cls: type, given: dict, name: str):
    """Nested settings from a mapping (a spec, a stored config), unknown keys named."""
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(given) - known)
    if unknown:
        raise UserError(
            f"CollectConfig.{name}: unknown setting {unknown[0]!r} (one of {sorted(known)})"
        )
    return cls(**given)


def ppo_preset(env_id: str) -> PPOSettings:
    """The paper's PPO settings for ``env_id`` (its ``EnvSpec.ppo``, docs/design.md section 3)."""
    n_steps, batch_size, n_epochs = get_spec(env_id).ppo
    return PPOSettings(n_steps=n_steps, batch_size=batch_size, n_epochs=n_epochs)


def default_collector(env_id: str, algo: str) -> str:
    """``collector="auto"``: the batched collector where it applies (PPO on an env with a batched
    core), else SB3 (the reference, one flag away everywhere)."""
    return "batched" if get_spec(env_id).batched is not None and algo == "ppo" else "sb3"


def parse_tasks(
    tasks: str | list[int] | tuple[int, ...], env_id: str, split_seed: int
) -> list[int]:
    """``all`` | ``train`` | ``test`` | ``fit`` | ``validation`` | ``PART:N`` (the first N of that
    part, for reduced-scale runs) | ``"0,3,7"`` | a list of ints -> sorted unique task indices."""
    spec = get_spec(env_id)
    if isinstance(tasks, str):
        key = tasks.strip().lower()
        if key == "all":
            return list(range(spec.num_tasks))
        part, _, count = key.partition(":")
        if part in SPLIT_PARTS:
            chosen = sorted(split_part(env_id, part, split_seed))
            if not count:
                return chosen
            if not count.isdigit() or int(count) < 1:
                raise UserError(f"tasks {tasks!r}: N in '{part}:N' must be a positive integer")
            if int(count) > len(chosen):  # a reduced-scale run that is not reduced: say so
                raise OutOfRangeError(
                    f"tasks {tasks!r}: {env_id}'s {part} part of split {split_seed} has "
                    f"{len(chosen)} tasks, fewer than {count}; use '{part}' for all of them"
                )
            return chosen[: int(count)]
        try:
            tasks = [int(t) for t in key.split(",") if t.strip()]
        except ValueError:
            raise UserError(
                f"tasks must be 'all', 'train', 'test', 'fit', 'validation' or a comma-separated "
                f"list of ints, got {tasks!r}"
            ) from None
    out = sorted({spec.check_task(int(t)) for t in tasks})
    if not out:
        raise UserError("tasks is empty: nothing to collect")
    return out


@dataclass
class CollectConfig:
    """How to collect learning histories.  Stored in the dataset's ``meta/info.json``.

    env_id: registered env id (``lhf envs``).
    tasks: ``train`` (the default: the train split of ``split_seed``, so its test tasks stay
        unseen), ``all``, ``test``, ``fit`` (the train tasks without the validation tasks: data
        for tuning runs), ``validation``, ``PART:N`` (the first N of that part), task indices
        ``0,3,7``, or a list of them (resolved to a sorted list).
    histories: learning histories per task (paper: 100).
    steps: transitions per history; a multiple of the env's horizon (paper: 1000, Meta-World 10,000).
    protocol: ``paper`` (one learner per task acting in ``histories`` parallel copies, one history per
        copy), ``independent`` (one independently seeded learner per history), ``noisy`` (``paper``
        with ``noisy_fraction`` of the histories made by a uniform random policy instead), or
        ``learners`` (``learners`` independently seeded learners per task, each acting in
        ``histories / learners`` parallel copies: histories that differ between learners, each
        learner learning as under ``paper`` from several streams).
    algo: source RL algorithm, ``ppo`` (any env) or ``sac`` (continuous actions only).
    collector: ``auto`` (``batched`` where it applies: PPO on an env with a batched core, the
        gridworlds; else ``sb3``, e.g. SAC or Meta-World), ``sb3`` (Stable-Baselines3, the
        reference, any env) or ``batched`` (every learner of a chunk of tasks trained at once with
        stacked parameters, the same PPO).  Resolved when the config is made: the dataset records
        the collector that ran, never ``auto``.
    seed: root seed; task t's learners are seeded from ``SeedSequence([seed, t])``.
    split_seed: seed of the train/test split (and of the Meta-World goals).
    workers: worker processes collecting tasks in parallel (default: all cores; 1 = in this process).
        It does not change the data.
    noisy_fraction: fraction of random histories under ``noisy``; their count is ``round(f * histories)``.
    learners: learners per task under ``learners`` (a divisor of ``histories``).
    ppo: PPO settings; defaults to the paper's for the env.
    sac: SAC settings.
    tasks_per_chunk: batched collector: tasks trained together (default: as many as fit in
        ~50M transitions).  Part of the data's identity: it sets the chunks' random streams.
    device: batched collector: where the stacked PPO learners act and learn, ``cpu`` or
        ``cuda[:N]`` (the environments always step on the CPU).  The same algorithm; on CUDA the
        random draws come from the device's generator, so the data differ from a CPU run's.
    ppo_backend: batched collector on the CPU: how the stacked PPO learners act and learn.
        ``kernel``: the C++ kernel (compiled on first use with the system's g++); ``torch``: torch
        ops (any device; the only choice on CUDA); ``auto``: whichever of the two one measured update
        found faster on this machine (cached per CPU), ``torch`` where the kernel does not build.
        The two draw their random numbers differently, so the data differ; the
        resolved choice is stored with the dataset, and ``lhf reproduce`` resolves it before
        hashing a collect stage (the stage's name says which backend made its data).
    """

    env_id: str
    tasks: str | list[int] = "train"
    histories: int = 100
    steps: int = 1000
    protocol: Protocol = "paper"
    algo: Algo = "ppo"
    collector: CollectorChoice = "auto"
    seed: int = 0
    split_seed: int = 0
    workers: int = field(default_factory=lambda: os.cpu_count() or 1)
    noisy_fraction: float = 0.3
    learners: int = 10
    ppo: PPOSettings | None = None
    sac: SACSettings = field(default_factory=SACSettings)
    tasks_per_chunk: int | None = None
    device: str = "cpu"
    ppo_backend: PpoBackend = "auto"

    def __post_init__(self) -> None:
        check_types(self)
        spec = get_spec(self.env_id)  # unknown ids: error listing the valid ones
        if self.protocol not in PROTOCOLS:
            raise UserError(
                f"CollectConfig.protocol must be one of {PROTOCOLS}, got {self.protocol!r}"
            )
        if self.algo not in ALGOS:
            raise UserError(f"CollectConfig.algo must be one of {ALGOS}, got {self.algo!r}")
        if self.collector == "auto":
            self.collector = default_collector(self.env_id, self.algo)
        if self.collector not in COLLECTORS:
            raise UserError(
                f"CollectConfig.collector must be one of {('auto', *COLLECTORS)}, got "
                f"{self.collector!r}"
            )
        if self.algo == "sac" and spec.is_discrete:
            raise UserError(
                f"CollectConfig.algo='sac' needs continuous actions; {self.env_id} has {spec.action_space}"
            )
        if self.histories < 1:
            raise UserError(f"CollectConfig.histories must be >= 1, got {self.histories!r}")
        if self.steps < spec.horizon or self.steps % spec.horizon:
            raise UserError(
                f"CollectConfig.steps must be a positive multiple of the horizon of {self.env_id} "
                f"({spec.horizon}), got {self.steps!r}"
            )
        if self.workers < 1:
            raise UserError(f"CollectConfig.workers must be >= 1, got {self.workers!r}")
        if not 0.0 <= self.noisy_fraction < 1.0:
            raise UserError(
                f"CollectConfig.noisy_fraction must be in [0, 1), got {self.noisy_fraction!r}"
            )
        if self.protocol == "noisy" and self.histories - self.num_random_histories < 1:
            raise UserError(
                f"CollectConfig: noisy protocol with {self.histories} histories leaves no learner histories"
            )
        if self.protocol == "learners" and not (
            1 <= self.learners <= self.histories and self.histories % self.learners == 0
        ):
            raise UserError(
                f"CollectConfig.learners must divide histories ({self.histories}) under the "
                f"learners protocol, got {self.learners!r}"
            )
        if isinstance(self.ppo, dict):
            self.ppo = _settings(PPOSettings, self.ppo, "ppo")
        if isinstance(self.sac, dict):
            self.sac = _settings(SACSettings, self.sac, "sac")
        for name in ("seed", "split_seed"):
            if getattr(self, name) < 0:
                raise UserError(f"CollectConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        if self.ppo is None:
            self.ppo = ppo_preset(self.env_id)
        self.tasks = parse_tasks(self.tasks, self.env_id, self.split_seed)
        if not re.fullmatch(r"cpu|cuda(:\d+)?", self.device):
            raise UserError(
                f"CollectConfig.device must be 'cpu' or 'cuda[:N]', got {self.device!r}"
            )
        if self.device != "cpu" and self.collector != "batched":
            raise UserError(
                f"CollectConfig.device={self.device!r} needs collector='batched' (SB3 runs on the CPU)"
            )
        if self.ppo_backend not in PPO_BACKENDS:
            raise UserError(
                f"CollectConfig.ppo_backend must be one of {PPO_BACKENDS}, got {self.ppo_backend!r}"
            )
        if self.ppo_backend == "kernel" and self.device != "cpu":
            raise UserError(
                f"CollectConfig.ppo_backend='kernel' runs on the CPU; device={self.device!r} needs 'torch'"
            )
        if self.collector == "batched":
            if spec.batched is None or self.algo != "ppo":
                raise UserError(
                    f"CollectConfig.collector='batched' runs PPO on envs with a batched core "
                    f"(the gridworlds only), got "
                    f"{self.env_id} with {self.algo}; use collector='sb3'"
                )
            if self.tasks_per_chunk is None:
                self.tasks_per_chunk = max(1, CHUNK_TRANSITIONS // self.frames_per_task)
            if self.tasks_per_chunk < 1:
                raise UserError(
                    f"CollectConfig.tasks_per_chunk must be >= 1, got {self.tasks_per_chunk!r}"
                )

    @property
    def horizon(self) -> int:
        return get_spec(self.env_id).horizon

    @property
    def episodes_per_history(self) -> int:
        return self.steps // self.horizon

    @property
    def num_random_histories(self) -> int:
        return round(self.noisy_fraction * self.histories) if self.protocol == "noisy" else 0

    @property
    def learners_per_task(self) -> int:
        """The learners that make one task's learner histories (random ones aside): 1 under
        ``paper`` and ``noisy``, one per history under ``independent``."""
        return {"independent": self.histories, "learners": self.learners}.get(self.protocol, 1)

    @property
    def frames_per_task(self) -> int:
        return self.histories * self.steps

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> CollectConfig:
        return cls(**d)

    def identity(self) -> dict:
        """The fields that determine the data (``workers`` does not): equal identity = same dataset."""
        d = self.to_dict()
        d.pop("workers")
        if self.protocol != "learners":
            d.pop("learners")  # no other protocol reads it (nor did datasets before the field)
        if self.collector == "sb3":
            d.pop("tasks_per_chunk")  # SB3 tasks do not depend on chunks
        if self.device == "cpu":
            d.pop("device")  # the default, absent from the identities of older datasets
        if self.collector == "sb3" or self.ppo_backend == "torch":
            d.pop("ppo_backend")  # SB3 has its own; "torch" is what datasets before the field used
        # the layout written: an unfinished collection of another layout is not resumed into this
        # one, and a reproduction's cached collection of another layout is collected anew
        d["layout_version"] = C.LAYOUT_VERSION
        return d
