"""Configuration of learning history filtering (paper section 4; docs/design.md section 5)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal, get_args

from lhf_hf.errors import UserError

from .types import check_types

Strategy = Literal["linear", "softmax", "none", "top-fraction"]
ScanOrder = Literal["descending", "dataset"]
STRATEGIES: tuple[str, ...] = get_args(Strategy)
SCAN_ORDERS: tuple[str, ...] = get_args(ScanOrder)
#: The settings each strategy reads (``filtering.resample``, ``filtering.select``): a sweep over
#: another one makes arms that select the same histories.  Linear sampling is invariant to
#: ``r_max`` (min-max normalisation cancels it); ``none`` keeps every history once.
READS: dict[str, frozenset[str]] = {
    "linear": frozenset({"lam", "seed", "scan_order"}),
    "softmax": frozenset({"lam", "alpha", "r_max", "seed", "scan_order"}),
    "none": frozenset(),
    "top-fraction": frozenset({"lam", "r_max", "fraction"}),
}


#: Largest lambda: Improvement is then below float resolution of U, and U's values stay plottable.
MAX_LAM = 1e6


@dataclass(frozen=True)
class FilterConfig:
    """How to filter (resample) the histories of a dataset.  Stored with every selection.

    strategy: ``linear`` and ``softmax`` are the paper's LHF sampling; ``none`` keeps every history
        once (the baseline); ``top-fraction`` keeps the best ``fraction`` of each task by U,
        repeated to the original count (a simpler filter to compare against).
    lam: lambda, the weight of Stability in U = Improvement + lambda * Stability (paper: 1).
    alpha: softmax temperature (paper's sensitivity study: 1/16 .. 1).
    fraction: share of each task kept by ``top-fraction``.
    seed: seed of the acceptance draws; task t uses ``SeedSequence([seed, t])``.
    r_max: maximal episode return used by the scores; None = the env's optimal return of each task
        (gridworlds).  Required for Meta-World.  Linear sampling is invariant to it (min-max
        normalisation cancels it); softmax is not.
    scan_order: order of the passes of Algorithm 1: ``descending`` U (the reference code) or
        ``dataset`` order.
    """

    strategy: Strategy = "linear"
    lam: float = 1.0
    alpha: float = 0.125
    fraction: float = 0.5
    seed: int = 0
    r_max: float | None = None
    scan_order: ScanOrder = "descending"

    def __post_init__(self) -> None:
        check_types(self)
        if self.strategy not in STRATEGIES:
            raise UserError(
                f"FilterConfig.strategy must be one of {STRATEGIES}, got {self.strategy!r}"
            )
        if not math.isfinite(self.lam) or not 0 <= self.lam <= MAX_LAM:
            raise UserError(
                f"FilterConfig.lam must be between 0 and {MAX_LAM:g}, got {self.lam!r} (beyond "
                "~1e3 Stability alone decides U; the paper's sweep tops at 1000)"
            )
        if self.seed < 0:  # numpy's seed sequences take none (its own message names no flag)
            raise UserError(f"FilterConfig.seed must be >= 0, got {self.seed!r}")
        if not math.isfinite(self.alpha) or self.alpha <= 0:
            raise UserError(f"FilterConfig.alpha must be > 0, got {self.alpha!r}")
        if not 0 < self.fraction <= 1:
            raise UserError(f"FilterConfig.fraction must be in (0, 1], got {self.fraction!r}")
        if self.r_max is not None and (not math.isfinite(self.r_max) or self.r_max <= 0):
            raise UserError(f"FilterConfig.r_max must be a positive return, got {self.r_max!r}")
        if self.scan_order not in SCAN_ORDERS:
            raise UserError(
                f"FilterConfig.scan_order must be one of {SCAN_ORDERS}, got {self.scan_order!r}"
            )

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
