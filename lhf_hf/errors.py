"""The one type of expected failure: ``UserError``.

An expected failure is one the user can act on: a bad flag or config value, a folder that is not
ours, a damaged or foreign file, a missing optional extra, an unreachable Hub.  ``lhf`` prints its
message as one line and exits 1 (``LHF_DEBUG=1`` adds the traceback).  Anything else (a
``TypeError``, a ``KeyError`` of a dict lookup, an ``IndexError``, a plain ``RuntimeError``) is a bug
of ours and keeps its traceback.

``UserError`` is a ``ValueError``, so ``except ValueError`` around a config still catches a bad
value.  The subclasses below also carry the builtin type their failure has always had in Python
(``except FileNotFoundError`` around a missing dataset still works).
"""

from __future__ import annotations


class UserError(ValueError):
    """An expected failure, said in one line: the message says what is wrong and what to do."""


class NotFoundError(UserError, FileNotFoundError):
    """A file or folder the command needs is not there."""

    def __init__(self, message: str):
        # one message, like every UserError (OSError's (errno, strerror) form is not used)
        super().__init__(message)

    def __str__(self) -> str:
        return str(self.args[0])


class UnknownNameError(UserError, KeyError):
    """A name that is not registered (an env id, an experiment, a field of a file)."""

    def __str__(self) -> str:  # KeyError's str() would quote the sentence
        return str(self.args[0])


class MissingExtraError(UserError, ImportError):
    """An optional dependency (``pip install 'lhf_hf[EXTRA]'``) is not installed."""


class UserRuntimeError(UserError, RuntimeError):
    """A run that cannot go on for a reason outside the code: another process, the machine, a
    remote service, a kernel that does not build here."""


class MissingFieldError(UnknownNameError):
    """A file ``lhf_hf`` reads lacks a field: damaged, or not written by ``lhf_hf``."""


class OutOfRangeError(UserError, IndexError):
    """An index outside what exists (a task index beyond the env's tasks)."""
