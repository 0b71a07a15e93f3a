"""The key of a seconds-per-unit rate: which kind of work a rate holds for.

Stage records (``stage.json``) and the shipped ``rates.json`` store it as text,
``kind|env|field|...|ctxN``; this type is the one place that writes and reads that layout:

- ``kind``: collect / derive / filter / train / evaluate;
- ``env``: the env id (none for a derivation or a filter, whose time does not depend on it);
- ``fields``: what else the rate depends on (collector and algo; objective, model preset and
  attention; planning and test-time context), in ``estimate``'s order;
- ``context``: the model's context length when it is not the env's default (a token's attention
  and an evaluation step's window grow with it, so a rate holds for one context), else none:
  keys of the default context carry no tag, as they were measured before the tag existed.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace

from lhf_hf.errors import UserError

SEP = "|"
_CONTEXT = re.compile(r"ctx(\d+)")


@dataclass(frozen=True)
class RateKey:
    kind: str
    env: str | None = None
    fields: tuple[str, ...] = ()
    context: int | None = None  # None: the env's default context

    def __post_init__(self):
        parts = [self.kind, *([] if self.env is None else [self.env]), *self.fields]
        if any(not isinstance(p, str) or not p or SEP in p for p in parts):
            raise UserError(f"a rate key's parts are non-empty text without {SEP!r}: {parts}")
        if self.env is None and (self.fields or self.context is not None):
            raise UserError(f"a {self.kind} rate key without an env has nothing else")
        if any(_CONTEXT.fullmatch(f) for f in self.fields):
            raise UserError(f"a context tag is RateKey.context, not a field: {self.fields}")
        if self.context is not None and (isinstance(self.context, bool) or self.context < 1):
            raise UserError(f"a rate key's context is a positive length, not {self.context!r}")

    @classmethod
    def parse(cls, text: str) -> RateKey:
        """The key written as ``text``; ``ValueError`` if it is not one (an empty part)."""
        kind, *rest = text.split(SEP)
        env = rest.pop(0) if rest else None
        context = None
        if rest and (m := _CONTEXT.fullmatch(rest[-1])):
            context = int(m.group(1))
            rest.pop()
        return cls(kind, env, tuple(rest), context)

    def __str__(self) -> str:
        tag = [] if self.context is None else [f"ctx{self.context}"]
        env = [] if self.env is None else [self.env]
        return SEP.join([self.kind, *env, *self.fields, *tag])

    def on(self, env: str) -> RateKey:
        """The same kind of work on another env (a twin's rate, ``estimate.twins``)."""
        return replace(self, env=env)

    def at(self, context: int | None) -> RateKey:
        """The same work at another model context (None: the env's default)."""
        return replace(self, context=context)

    @property
    def without_env(self) -> str:
        """The key less its env, in words (a coverage row names the env already):
        ``evaluate dicp paper plan window ctx200``."""
        tag = [] if self.context is None else [f"ctx{self.context}"]
        return " ".join([self.kind, *self.fields, *tag])
