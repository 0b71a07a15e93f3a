"""Attention of a DICP planner's tree of imagined tokens as a C++ kernel
(``kernels/tree_attention.cpp``), forward only, and its torch reference.

At each depth the planner (``lhf_hf.evaluation.planning``) appends ``nb`` groups of ``per_beam``
new tokens (a beam's imagined transition token, then its query-action tokens) to a cached context.
New token ``i`` of group ``j`` (``i = j * per_beam + t``) attends to

- the context's keys ``[ctx_lo[i], L0)``;
- its beam's path: ``plen`` tokens of earlier depths;
- the first ``shared`` new tokens of its group (at most ``t`` of them) and itself;

the reference search's semantics (each imagined token sees its window of the context and its own
path only).  The torch path of the planner computes the same function as one SDPA call over the
context and the whole tree with a mask; this kernel computes only the visible scores
(BENCHMARKS.md, "DICP planning against its floor").

Each beam's path lives in a buffer of its own, (d, Pc) keys and values transposed per (batch, key
head, beam slot) (``path_buffers``): a call builds beam ``j``'s from the previous depth's buffers,
``src[parent[j]]``'s first ``plen - 1`` columns and its column ``src_col[j]`` (the token the beam
continues with), then appends the group's new keys and values; the next depth reads it as ``src``.

Threads: the (batch, key/value head) pairs are independent, so ``[0, B * Hkv)`` is split into
pieces that ``torch.get_num_threads()`` threads take in turn (``lhf_hf.utils.native_run``).
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

import torch

from lhf_hf.utils import native_build
from lhf_hf.utils.native_build import KernelUnavailable
from lhf_hf.utils.native_run import run_pieces

SOURCE = Path(__file__).parent / "kernels" / "tree_attention.cpp"
ABI_VERSION = 2
HEAD_DIMS = (8, 16)  # the kernel's compiled head dimensions (every preset's is 8)
# a call is 0.1-50 ms of work (one layer of one depth), each piece a Python round trip
_PIECES_PER_THREAD = 4

__all__ = [
    "KernelUnavailable",
    "available",
    "forward",
    "path_buffers",
    "read_paths",
    "reference",
    "transposed",
    "unsupported",
]


class TreeArgs(ctypes.Structure):
    """Mirror of ``struct TreeArgs`` in tree_attention.cpp (same field order)."""

    _fields_ = [
        *(
            (name, ctypes.c_int64)
            for name in ("B", "H", "Hkv", "D", "L0", "Lp", "n", "nb", "per_beam", "shared")
        ),
        *((name, ctypes.c_int64) for name in ("beams", "Pc", "plen")),
        *((f"{t}_s", ctypes.c_int64 * 3) for t in ("q", "k", "v", "o")),
        *((name, ctypes.c_void_p) for name in ("q", "k", "v", "kct", "vct")),
        *((name, ctypes.c_void_p) for name in ("src_k", "src_v", "dst_k", "dst_v")),
        *((name, ctypes.c_void_p) for name in ("parent", "src_col", "ctx_lo", "o")),
        ("scale", ctypes.c_float),
    ]


ERRORS = {1: "bad sizes", 2: "out of memory", 3: "a key index is out of bounds", 4: "head dim"}


@functools.cache
def build() -> Path:
    """Compile the kernel unless cached (``lhf_hf.utils.native_build``); returns the .so path."""
    return native_build.build_library(SOURCE, "tree_attention")


@functools.cache
def load() -> ctypes.CDLL:
    lib = native_build.open_verified(build)
    if lib.lhf_tree_abi_version() != ABI_VERSION:
        raise KernelUnavailable(f"{lib._name} does not match this lhf_hf (ABI)")
    lib.lhf_tree_forward.argtypes = [ctypes.POINTER(TreeArgs), ctypes.c_int64, ctypes.c_int64]
    lib.lhf_tree_forward.restype = ctypes.c_int
    lib.lhf_tree_vector_width.restype = ctypes.c_int
    return lib


def available() -> str | None:
    """Why the kernel cannot run on this machine (None when it can): it builds and loads."""
    try:
        load()
    except KernelUnavailable as exc:
        return str(exc)
    return None


def unsupported(head_dim: int, dtype: torch.dtype, device: torch.device) -> str | None:
    """Why the kernel cannot compute this attention (None when it can)."""
    if device.type != "cpu":
        return f"the tree attention kernel runs on the CPU (the model is on {device.type})"
    if dtype != torch.float32:
        return f"the tree attention kernel computes in float32 (the model is {dtype})"
    if head_dim not in HEAD_DIMS:
        return f"the tree attention kernel has head dims {HEAD_DIMS}, this model {head_dim}"
    return available()


def _padded(n: int) -> int:
    """``n`` rounded up to a multiple of the kernel's vector width (at least one vector)."""
    vw = load().lhf_tree_vector_width()
    return max(-(-n // vw) * vw, vw)


def transposed(x: torch.Tensor) -> torch.Tensor:
    """(B, Hkv, L0, d) context keys or values -> (B, Hkv, d, Lp) float32, contiguous, zero-padded
    to a multiple of the kernel's vector width: the layout the kernel reads."""
    B, Hkv, L0, d = x.shape
    out = torch.empty(B, Hkv, d, _padded(L0))
    out[..., :L0] = x.transpose(-1, -2)
    out[..., L0:] = 0  # read in the last vector, masked: finite values, weight 0
    return out


def path_buffers(B: int, Hkv: int, beams: int, d: int, tokens: int) -> tuple:
    """Keys and values (B, Hkv, beams, d, Pc) for ``beams`` paths of at most ``tokens`` tokens
    (path and new tokens of a depth), uninitialised: the kernel writes what it reads."""
    shape = (B, Hkv, beams, d, _padded(tokens))
    return torch.empty(shape), torch.empty(shape)


def read_paths(buffer: torch.Tensor, nb: int, tokens: int) -> torch.Tensor:
    """(B, nb, tokens, Hkv, d) the first ``tokens`` columns of the first ``nb`` beams' buffers."""
    return buffer[:, :, :nb, :, :tokens].permute(0, 2, 4, 1, 3)


def _strides(t: torch.Tensor) -> tuple[int, int, int]:
    """(batch, token, head) element strides of a (B, n, H, d) tensor whose d is contiguous."""
    if t.stride(-1) != 1 or t.dtype != torch.float32:
        raise ValueError(f"the tree kernel reads float32 rows with d contiguous, got {t.dtype}, "
                         f"strides {t.stride()}")  # fmt: skip
    return t.stride(0), t.stride(1), t.stride(2)


def forward(
    q: torch.Tensor,
    k: torch.Tensor,
    v: torch.Tensor,
    kct: torch.Tensor,
    vct: torch.Tensor,
    L0: int,
    src: tuple | None,
    dst: tuple,
    parent: torch.Tensor | None,
    src_col: torch.Tensor | None,
    plen: int,
    ctx_lo: torch.Tensor,
    per_beam: int,
    shared: int,
    scale: float,
    out: torch.Tensor | None = None,
) -> torch.Tensor:
    """The new tokens' attention outputs (B, n, H, d), into ``out`` if given (contiguous).

    q: (B, n, H, d) the new tokens' queries (RoPE applied); k, v: (B, n, Hkv, d) their keys and
    values (d contiguous, any other strides); kct, vct: (B, Hkv, d, Lp) the context's keys and
    values (``transposed``), L0 of them; src, dst: (keys, values) ``path_buffers`` of the previous
    depth (None at the first) and of this one (written); parent, src_col: (B, nb) int32, each
    beam's parent in ``src`` and the column of the token it continues with (None at the first
    depth); plen: the path length (0 at the first depth); ctx_lo: (n,) int32."""
    B, n, H, d = q.shape
    dst_k, dst_v = dst
    Hkv, beams, Pc = dst_k.shape[1], dst_k.shape[2], dst_k.shape[4]
    for t in (kct, vct, dst_k, dst_v, *(src or ())):
        if not t.is_contiguous() or t.dtype != torch.float32:
            raise ValueError(
                "the tree kernel's context and path buffers must be contiguous float32"
            )
    if src is not None and (src[0].shape != dst_k.shape or src[1].shape != dst_k.shape):
        raise ValueError(f"path buffers differ: {src[0].shape} vs {dst_k.shape}")
    if (plen > 0) != (src is not None and parent is not None and src_col is not None):
        raise ValueError("a path (plen > 0) needs src, parent and src_col; the first depth none")
    out = torch.empty(B, n, H, d) if out is None else out
    if out.shape != q.shape or not out.is_contiguous():
        raise ValueError(f"out must be a contiguous {tuple(q.shape)} tensor")
    keep = [ctx_lo.to(torch.int32).contiguous()]
    a = TreeArgs()
    a.B, a.H, a.Hkv, a.D = B, H, Hkv, d
    a.L0, a.Lp = L0, kct.shape[-1]
    a.n, a.nb, a.per_beam, a.shared = n, n // per_beam, per_beam, shared
    a.beams, a.Pc, a.plen = beams, Pc, plen
    for name, t in (("q", q), ("k", k), ("v", v), ("o", out)):
        getattr(a, f"{name}_s")[:] = _strides(t)
    a.q, a.k, a.v, a.o = q.data_ptr(), k.data_ptr(), v.data_ptr(), out.data_ptr()
    a.kct, a.vct = kct.data_ptr(), vct.data_ptr()
    a.dst_k, a.dst_v = dst_k.data_ptr(), dst_v.data_ptr()
    a.ctx_lo = keep[0].data_ptr()
    if plen > 0:
        keep += [parent.to(torch.int32).contiguous(), src_col.to(torch.int32).contiguous()]
        if keep[1].shape != (B, a.nb) or keep[2].shape != (B, a.nb):
            raise ValueError(f"parent and src_col must be ({B}, {a.nb})")
        a.src_k, a.src_v = src[0].data_ptr(), src[1].data_ptr()
        a.parent, a.src_col = keep[1].data_ptr(), keep[2].data_ptr()
    a.scale = scale
    run_pieces(load().lhf_tree_forward, ctypes.byref(a), B * Hkv, torch.get_num_threads(),
               _PIECES_PER_THREAD, "tree attention kernel", ERRORS)  # fmt: skip
    return out


def reference(
    q: torch.Tensor,
    k: torch.Tensor,
    v: torch.Tensor,
    k_ctx: torch.Tensor,
    v_ctx: torch.Tensor,
    path_k: torch.Tensor,
    path_v: torch.Tensor,
    ctx_lo: torch.Tensor,
    per_beam: int,
    shared: int,
    scale: float,
) -> torch.Tensor:
    """``forward``'s function in torch ops (tests): k_ctx, v_ctx (B, Hkv, L0, d) untransposed;
    path_k, path_v (B, nb, plen, Hkv, d) each beam's path."""
    B, n, H, d = q.shape
    Hkv, L0, plen = k_ctx.shape[1], k_ctx.shape[2], path_k.shape[2]
    t = torch.arange(n) % per_beam
    beam = torch.arange(n) // per_beam
    # (B, n, plen + per_beam, Hkv, d): each token's path, then its group's new tokens
    group_k = k.reshape(B, n // per_beam, per_beam, Hkv, d)[:, beam]
    group_v = v.reshape(B, n // per_beam, per_beam, Hkv, d)[:, beam]
    gk = torch.cat([path_k[:, beam], group_k], dim=2)
    gv = torch.cat([path_v[:, beam], group_v], dim=2)
    col = torch.arange(per_beam)
    sees = (col < torch.clamp(t, max=shared)[:, None]) | (col == t[:, None])  # (n, per_beam)
    seen = torch.cat([torch.ones(n, plen, dtype=torch.bool), sees], dim=1)  # (n, plen + per_beam)
    ctx_seen = torch.arange(L0) >= ctx_lo.long()[:, None]  # (n, L0)
    rep = H // Hkv
    kc = k_ctx.repeat_interleave(rep, 1)  # (B, H, L0, d)
    vc = v_ctx.repeat_interleave(rep, 1)
    gk = gk.repeat_interleave(rep, 3).permute(0, 3, 1, 2, 4)  # (B, H, n, keys, d)
    gv = gv.repeat_interleave(rep, 3).permute(0, 3, 1, 2, 4)
    qh = q.permute(0, 2, 1, 3) * scale  # (B, H, n, d)
    s_ctx = (qh @ kc.transpose(-1, -2)).masked_fill(~ctx_seen, float("-inf"))  # (B, H, n, L0)
    s_tree = torch.einsum("bhnd,bhnkd->bhnk", qh, gk).masked_fill(~seen, float("-inf"))
    p = torch.softmax(torch.cat([s_ctx, s_tree], dim=-1), dim=-1)
    out = p[..., :L0] @ vc + torch.einsum("bhnk,bhnkd->bhnd", p[..., L0:], gv)  # (B, H, n, d)
    return out.permute(0, 2, 1, 3)  # (B, n, H, d)
