"""Build, load and call the C++ PPO-update kernel (``kernels/ppo_update.cpp``).

The kernel is compiled on first use and cached by ``lhf_hf.utils.native_build`` (``$CXX``,
``$LHF_HF_KERNEL_CACHE``, ``$LHF_HF_KERNEL_MARCH``: a private cache, a library loaded only when its
SHA-256 is the one recorded at its build).  No compiler, or a failed build, raises
:class:`KernelUnavailable` with the reason; the ``auto`` gradients mode of
:func:`lhf_hf.collection.ppo_backends.ppo_update` then falls back to the torch implementation.

Threads: learners are independent, so ``[0, L)`` is split into contiguous pieces (8 per thread) that
``torch.get_num_threads()`` threads take in turn, one foreign call each; ctypes releases the GIL for
the call's duration.  Results do not depend on the split.
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

import torch

from lhf_hf.errors import UserError
from lhf_hf.utils import native_build
from lhf_hf.utils.native_build import (  # noqa: F401 (this module's API before the move)
    FLAGS,
    KernelUnavailable,
    cache_dir,
    private_cache_dir,
    target_march,
)
from lhf_hf.utils.native_run import run_pieces

SOURCE = Path(__file__).parent / "kernels" / "ppo_update.cpp"
ABI_VERSION = 1


class PPOArgs(ctypes.Structure):
    """Mirror of ``struct PPOArgs`` in ppo_update.cpp (same field order)."""

    _fields_ = [
        *((name, ctypes.c_int64) for name in ("L", "N", "d", "A", "batch", "n_epochs")),
        ("params", ctypes.c_void_p * 6),
        ("exp_avg", ctypes.c_void_p * 6),
        ("exp_avg_sq", ctypes.c_void_p * 6),
        *((name, ctypes.c_void_p) for name in ("obs", "actions", "old_logp", "advantages")),
        ("returns", ctypes.c_void_p),
        ("perms", ctypes.c_void_p),
        ("seed", ctypes.c_uint64),
        *((name, ctypes.c_double) for name in ("lr", "beta1", "beta2", "eps", "step0")),
        *((name, ctypes.c_double) for name in ("clip_range", "vf_coef", "max_grad_norm")),
    ]


class ActArgs(ctypes.Structure):
    """Mirror of ``struct ActArgs`` in ppo_update.cpp."""

    _fields_ = [
        *((name, ctypes.c_int64) for name in ("L", "E", "d", "A")),
        ("params", ctypes.c_void_p * 6),
        *((name, ctypes.c_void_p) for name in ("obs", "uniforms", "actions", "logp", "values")),
    ]


def _native_target(cxx: str, march: str = "native") -> str:
    """The compiler's expansion of ``-march=MARCH`` (part of the cache key; tests replace it)."""
    return native_build.native_target(cxx, march)


@functools.cache
def build(hidden: int = 64) -> Path:
    """Compile the kernel for a hidden width (a multiple of 16) unless cached; returns the .so path."""
    if hidden % 16 != 0 or hidden <= 0:
        raise KernelUnavailable(
            f"the kernel needs a hidden width that is a multiple of 16, got {hidden}"
        )
    return native_build.build_library(
        SOURCE,
        f"ppo_update-h{hidden}",
        (f"-DHID={hidden}",),
        describe_target=lambda cxx, march: _native_target(cxx, march),
    )


@functools.cache
def load(hidden: int = 64) -> ctypes.CDLL:
    lib = native_build.open_verified(build, hidden)
    if lib.lhf_abi_version() != ABI_VERSION or lib.lhf_hidden() != hidden:
        raise KernelUnavailable(f"{lib._name} does not match this lhf_hf (ABI or hidden width)")
    lib.lhf_ppo_update.argtypes = [ctypes.POINTER(PPOArgs), ctypes.c_int64, ctypes.c_int64]
    lib.lhf_ppo_update.restype = ctypes.c_int
    lib.lhf_ppo_act.argtypes = [ctypes.POINTER(ActArgs), ctypes.c_int64, ctypes.c_int64]
    lib.lhf_ppo_act.restype = ctypes.c_int
    return lib


def _run(fn, ref, L: int, threads: int | None) -> None:
    """fn(ref, l0, l1) over the L learners, 8 pieces per thread (``utils.native_run``)."""
    run_pieces(fn, ref, L, threads or torch.get_num_threads(), 8, "PPO kernel", ERRORS)


def ppo_act(
    params: list[torch.Tensor],
    obs: torch.Tensor,
    uniforms: torch.Tensor | None,
    threads: int | None = None,
) -> tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor]:
    """Act with every learner: ``obs`` (L, E, d) -> (actions (L, E) int64, log-probs, values).

    ``params``: W1, B1, W2, B2, W3, B3 of the stacked 2L nets (float32, contiguous).  Action e of
    learner l is the inverse CDF of its policy at ``uniforms[l, e]`` (in [0, 1)); ``uniforms=None``
    computes the values only (actions and log-probs are then None).
    """
    lib = load(params[0].shape[-1])
    obs = obs.to(torch.float32).contiguous()
    L, E, d = obs.shape
    A = params[4].shape[-1]
    values = torch.empty(L, E)
    args = ActArgs()
    args.L, args.E, args.d, args.A = L, E, d, A
    for i in range(6):
        args.params[i] = params[i].data_ptr()
    args.obs, args.values = obs.data_ptr(), values.data_ptr()
    actions = logp = None
    if uniforms is not None:
        uniforms = uniforms.to(torch.float32).contiguous()
        if uniforms.shape != (L, E):
            raise UserError(f"uniforms: expected shape ({L}, {E}), got {tuple(uniforms.shape)}")
        actions, logp = torch.empty(L, E, dtype=torch.int64), torch.empty(L, E)
        args.uniforms, args.actions, args.logp = (
            uniforms.data_ptr(),
            actions.data_ptr(),
            logp.data_ptr(),
        )
    _run(lib.lhf_ppo_act, ctypes.byref(args), L, threads)
    return actions, logp, values


ERRORS = {
    1: "bad sizes",
    2: "out of memory",
    3: "a permutation index is out of range",
    4: "an action is out of range",
}


def ppo_update_kernel(
    tensors: dict[str, torch.Tensor],
    params: list[torch.Tensor],
    exp_avg: list[torch.Tensor],
    exp_avg_sq: list[torch.Tensor],
    *,
    n_epochs: int,
    batch_size: int,
    perms: torch.Tensor | None,
    seed: int,
    lr: float,
    betas: tuple[float, float],
    eps: float,
    step0: float,
    clip_range: float,
    vf_coef: float,
    max_grad_norm: float,
    threads: int | None = None,
) -> None:
    """One PPO update of every learner in place (params and Adam moments).

    ``tensors``: contiguous CPU ``obs`` (L, N, d) float32, ``actions`` (L, N) int64, ``old_logp``,
    ``advantages``, ``returns`` (L, N) float32.  ``params`` / moments: W1, B1, W2, B2, W3, B3 of the
    stacked 2L nets.  ``perms``: (n_epochs, L, N) int64, or None to draw them from ``seed``.
    """
    hidden = params[0].shape[-1]
    lib = load(hidden)
    obs = tensors["obs"]
    L, N, d = obs.shape
    A = params[4].shape[-1]
    args = PPOArgs()
    args.L, args.N, args.d, args.A, args.batch, args.n_epochs = L, N, d, A, batch_size, n_epochs
    for i in range(6):
        args.params[i] = params[i].data_ptr()
        args.exp_avg[i] = exp_avg[i].data_ptr()
        args.exp_avg_sq[i] = exp_avg_sq[i].data_ptr()
    for name in ("obs", "actions", "old_logp", "advantages", "returns"):
        setattr(args, name, tensors[name].data_ptr())
    args.perms = perms.data_ptr() if perms is not None else None
    args.seed = seed
    args.lr, (args.beta1, args.beta2), args.eps, args.step0 = lr, betas, eps, step0
    args.clip_range, args.vf_coef, args.max_grad_norm = clip_range, vf_coef, max_grad_norm
    _run(lib.lhf_ppo_update, ctypes.byref(args), L, threads)
