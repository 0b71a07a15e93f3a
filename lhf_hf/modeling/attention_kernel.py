"""The training attention as a C++ kernel (``kernels/train_attention.cpp``): forward and backward of

    P = softmax(Q K^T * scale over the allowed keys);  out = (P * keep / (1 - p)) V

with the dropout mask drawn from a counter-based hash of (seed, batch, head, query, key) inside the
kernel, never stored; registered as the ``transformers`` attention implementation ``lhf_kernel``.

Why (BENCHMARKS.md, "Training near the FLOP floor"): at the paper's head dimension 8 torch's
attention streams every (L, L) score tensor through memory several times (scores, softmax, mask,
products, their gradients); at context 200 that was ~70 % of an AD training step.  The kernel keeps
one (batch, head) in L1 and saves only each row's log-sum-exp for the backward.

Which keys a query sees must be a range per row, shared by the batch and the heads: causal attention
(no mask) and the band mask of ``attention="band"`` are; any other case runs the torch path
(``lhf_sdpa``, :mod:`.train_attention`), as do non-CPU tensors, dtypes other than float32, autocast,
head dimensions other than 8 and 16, more keys than queries (a KV cache), a mask that takes
gradients, ``softcap`` and ``position_bias``.

Reproducibility: each call draws a 64-bit seed from torch's default CPU generator (seeded by
``TrainConfig.seed`` through ``transformers.set_seed``); the mask is a function of that seed and the
element's coordinates only (not of threads or the split of heads between them), and the backward
redraws it from the saved seed.  It is another mask than the torch path's for the same seed, so
which one trained a model is part of the run's identity (``TrainConfig.attention_kernel``).

This file is not part of a checkpoint's code bundle (``remote_code``): a model trained with it is
evaluated (without dropout) by the bundled ``lhf_sdpa``/SDPA, the same function.

Threads: heads are independent, so ``[0, B * H)`` is split into contiguous pieces that
``torch.get_num_threads()`` threads take in turn, one foreign call each (ctypes releases the GIL).
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

import torch
from transformers import AttentionInterface
from transformers.integrations.sdpa_attention import repeat_kv
from transformers.masking_utils import ALL_MASK_ATTENTION_FUNCTIONS, sdpa_mask

from lhf_hf.utils import native_build
from lhf_hf.utils.native_build import KernelUnavailable
from lhf_hf.utils.native_run import run_pieces

from . import train_attention

NAME = "lhf_kernel"  # the ``attn_implementation`` a training with TrainConfig.attention_kernel="kernel" sets
SOURCE = Path(__file__).parent / "kernels" / "train_attention.cpp"
ABI_VERSION = 1
HEAD_DIMS = (8, 16)  # the kernel's compiled head dimensions (every preset's is 8)
# few: a layer's call is 1-40 ms of work (contexts 80-200, batch 64), each piece a Python round trip
_PIECES_PER_THREAD = 2

__all__ = ["NAME", "KernelUnavailable", "available", "attention_forward", "keep_mask"]


class AttnArgs(ctypes.Structure):
    """Mirror of ``struct AttnArgs`` in train_attention.cpp (same field order)."""

    _fields_ = [
        *((name, ctypes.c_int64) for name in ("B", "H", "L", "D")),
        *((f"{t}_s", ctypes.c_int64 * 3) for t in ("q", "k", "v", "o", "do", "dq", "dk", "dv")),
        *((name, ctypes.c_void_p) for name in ("q", "k", "v", "o", "lse", "dout")),
        *((name, ctypes.c_void_p) for name in ("dq", "dk", "dv", "lo", "hi")),
        ("scale", ctypes.c_float),
        ("keep_scale", ctypes.c_float),
        ("threshold", ctypes.c_uint32),
        ("seed", ctypes.c_uint64),
    ]


ERRORS = {1: "bad sizes", 2: "out of memory", 3: "a key range is out of bounds", 4: "head dim"}


@functools.cache
def build() -> Path:
    """Compile the kernel unless cached (``lhf_hf.utils.native_build``); returns the .so path."""
    return native_build.build_library(SOURCE, "train_attention")


@functools.cache
def load() -> ctypes.CDLL:
    lib = native_build.open_verified(build)
    if lib.lhf_attn_abi_version() != ABI_VERSION:
        raise KernelUnavailable(f"{lib._name} does not match this lhf_hf (ABI)")
    for fn in (lib.lhf_attn_forward, lib.lhf_attn_backward):
        fn.argtypes = [ctypes.POINTER(AttnArgs), ctypes.c_int64, ctypes.c_int64]
        fn.restype = ctypes.c_int
    lib.lhf_attn_keep_mask.argtypes = [ctypes.POINTER(AttnArgs), ctypes.c_void_p]
    lib.lhf_attn_keep_mask.restype = None
    lib.lhf_attn_exp.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64]
    lib.lhf_attn_exp.restype = None
    return lib


def available() -> str | None:
    """Why the kernel cannot run on this machine (None when it can): it builds and loads."""
    try:
        load()
    except KernelUnavailable as exc:
        return str(exc)
    return None


def _run(fn, args: AttnArgs, n: int) -> None:
    """fn(args, h0, h1) over heads [0, n), in pieces pulled by torch's thread count."""
    run_pieces(fn, ctypes.byref(args), n, torch.get_num_threads(), _PIECES_PER_THREAD,
               "attention kernel", ERRORS)  # fmt: skip


def _threshold(p: float) -> int:
    """A weight is kept iff its 32 random bits are >= this: p rounded to a multiple of 2^-32."""
    return min(round(p * 2**32), 2**32 - 1)


def _args(q: torch.Tensor, lo, hi, scale: float, p: float, seed: int) -> AttnArgs:
    a = AttnArgs()
    a.B, a.H, a.L, a.D = q.shape
    a.lo, a.hi = lo.data_ptr(), hi.data_ptr()
    a.scale = scale
    threshold = _threshold(p) if p > 0 else 0
    a.threshold = threshold
    a.keep_scale = 1.0 / (1.0 - threshold / 2**32)  # exact expectation for the rounded p
    a.seed = seed
    return a


def _set(a: AttnArgs, name: str, t: torch.Tensor) -> None:
    """Pointer and (batch, head, position) strides of a (B, H, L, D) tensor with D contiguous."""
    setattr(a, name, t.data_ptr())
    strides = getattr(a, f"{name}_s")
    strides[0], strides[1], strides[2] = t.stride(0), t.stride(1), t.stride(2)


def _rows(t: torch.Tensor) -> torch.Tensor:
    """``t`` (B, H, L, D) float32 with its last axis contiguous (any other layout is read as is)."""
    return t if t.stride(-1) == 1 else t.contiguous()


def _blhd(B: int, H: int, L: int, D: int) -> torch.Tensor:
    """A new (B, H, L, D) tensor laid out as (B, L, H, D): the layout of the projections' views,
    so that the transpose back to (B, L, H * D) is free."""
    return torch.empty(B, L, H, D).transpose(1, 2)


class KernelAttention(torch.autograd.Function):
    """q, k, v (B, H, L, D) float32 -> out (B, L, H, D); lo, hi (L,) int32 key ranges."""

    @staticmethod
    def forward(ctx, q, k, v, lo, hi, scale: float, p: float, seed: int):
        q, k, v = _rows(q), _rows(k), _rows(v)
        B, H, L, D = q.shape
        out = _blhd(B, H, L, D)  # (B, H, L, D) view of (B, L, H, D)
        lse = torch.empty(B, H, L)
        a = _args(q, lo, hi, scale, p, seed)
        for name, t in (("q", q), ("k", k), ("v", v), ("o", out)):
            _set(a, name, t)
        a.lse = lse.data_ptr()
        _run(load().lhf_attn_forward, a, B * H)
        ctx.save_for_backward(q, k, v, out, lse, lo, hi)
        ctx.scale, ctx.p, ctx.seed = scale, p, seed
        return out.transpose(1, 2)  # (B, L, H, D), contiguous

    @staticmethod
    def backward(ctx, grad_out):
        q, k, v, out, lse, lo, hi = ctx.saved_tensors
        B, H, L, D = q.shape
        grad = _rows(grad_out.transpose(1, 2))  # (B, H, L, D)
        dq, dk, dv = _blhd(B, H, L, D), _blhd(B, H, L, D), _blhd(B, H, L, D)
        a = _args(q, lo, hi, ctx.scale, ctx.p, ctx.seed)
        for name, t in (("q", q), ("k", k), ("v", v), ("o", out), ("do", grad)):
            _set(a, name, t)
        for name, t in (("dq", dq), ("dk", dk), ("dv", dv)):
            _set(a, name, t)
        a.lse, a.dout = lse.data_ptr(), grad.data_ptr()
        _run(load().lhf_attn_backward, a, B * H)
        return dq, dk, dv, None, None, None, None, None


def key_ranges(
    attention_mask: torch.Tensor | None, L: int
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(lo, hi) int32 (L,): query i may attend to keys [lo_i, hi_i); None when the mask is not
    such a range per row shared by the batch and the heads (then the torch path runs).

    attention_mask: None (causal), or bool (True = may attend) / additive float (0 or -inf) of
    shape (B or 1, 1, L, L), the same for every batch element (an ``expand`` of one, as
    ``ICRLModel.band_attention`` builds it, is checked for free; a materialised one is compared)."""
    if attention_mask is None:
        lo = torch.zeros(L, dtype=torch.int32)
        return lo, torch.arange(1, L + 1, dtype=torch.int32)
    m = attention_mask
    if m.dim() != 4 or m.shape[1] != 1 or m.shape[-2:] != (L, L):
        return None
    if m.shape[0] > 1 and m.stride(0) != 0 and not torch.equal(m, m[:1].expand_as(m)):
        return None  # a mask per batch element (padding)
    m = m[0, 0]
    if m.dtype == torch.bool:
        allowed = m
    else:
        allowed = m == 0
        if not bool((allowed | torch.isneginf(m)).all()):  # a bias other than 0 / -inf
            return None
    count = allowed.sum(1)  # (L,)
    lo = allowed.to(torch.uint8).argmax(1)  # first allowed key (0 for an empty row)
    hi = lo + count
    j = torch.arange(L)
    if not torch.equal(allowed, (j >= lo[:, None]) & (j < hi[:, None])):
        return None
    return lo.to(torch.int32), hi.to(torch.int32)


def _torch_path_does_it(query, key, attention_mask, kwargs) -> bool:
    """The cases this module leaves to the torch path (module docstring)."""
    return (
        train_attention.outside_cpu_paths(query, attention_mask, kwargs)
        or query.dtype != torch.float32
        or query.shape[-1] not in HEAD_DIMS
        or key.shape[2] != query.shape[2]
    )


def attention_forward(
    module: torch.nn.Module,
    query: torch.Tensor,
    key: torch.Tensor,
    value: torch.Tensor,
    attention_mask: torch.Tensor | None,
    dropout: float = 0.0,
    scaling: float | None = None,
    **kwargs,
) -> tuple[torch.Tensor, None]:
    """``transformers`` attention interface: query (B, H, L, d), key/value (B, Hkv, L, d) ->
    ((B, L, H, d), None); the masks as ``train_attention.attention_forward`` reads them."""
    L = query.shape[2]
    is_causal = kwargs.get("is_causal")
    is_causal = getattr(module, "is_causal", True) if is_causal is None else is_causal
    ranges = None
    if not _torch_path_does_it(query, key, attention_mask, kwargs) and 0 <= dropout < 1:
        if attention_mask is None and not (bool(is_causal) and L > 1):
            ranges = torch.zeros(L, dtype=torch.int32), torch.full((L,), L, dtype=torch.int32)
        else:
            ranges = key_ranges(attention_mask, L)
    if ranges is None:
        return train_attention.attention_forward(
            module, query, key, value, attention_mask, dropout=dropout, scaling=scaling, **kwargs
        )
    groups = getattr(module, "num_key_value_groups", 1)
    key, value = repeat_kv(key, groups), repeat_kv(value, groups)  # (B, H, L, d)
    scale = query.shape[-1] ** -0.5 if scaling is None else scaling
    seed = int(torch.randint(-(2**63), 2**63 - 1, (), dtype=torch.int64)) % 2**64 if dropout else 0
    out = KernelAttention.apply(query, key, value, *ranges, scale, float(dropout), seed)
    return out, None  # (B, L, H, d)


def keep_mask(B: int, H: int, L: int, p: float, seed: int) -> torch.Tensor:
    """(B, H, L, L) bool: the weights a kernel call with this seed keeps (True) and drops."""
    q = torch.empty(B, H, L, 1)
    a = _args(q, torch.zeros(L, dtype=torch.int32), torch.zeros(L, dtype=torch.int32), 1.0, p, seed)
    out = torch.empty(B, H, L, L, dtype=torch.uint8)
    load().lhf_attn_keep_mask(ctypes.byref(a), out.data_ptr())
    return out.bool()


def kernel_exp(x: torch.Tensor) -> torch.Tensor:
    """The kernel's exp (tests check its error against float64)."""
    x = x.to(torch.float32).contiguous()
    y = torch.empty_like(x)
    load().lhf_attn_exp(x.data_ptr(), y.data_ptr(), x.numel())
    return y


def drop_probability(p: float) -> float:
    """The drop probability the kernel draws with: p rounded to a multiple of 2^-32."""
    return _threshold(p) / 2**32 if p > 0 else 0.0


AttentionInterface.register(NAME, attention_forward)
# the masks SDPA gets (None for plain causal attention, which the kernel handles itself)
ALL_MASK_ATTENTION_FUNCTIONS.register(NAME, sdpa_mask)
