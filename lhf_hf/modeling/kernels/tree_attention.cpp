// Inference attention of a DICP planner's tree of imagined tokens (lhf_hf/evaluation/planning.py):
// forward only, no dropout, small head dimensions.
//
// The planner appends, at each depth of its beam search, a group of `per_beam` new tokens per
// beam (the beam's imagined transition token T, then one query-action token Q per action) to a
// shared, cached context.  Each new token attends to
//
//   - the context's keys [lo_i, L0) (the oldest ones drop out of the token's window as its path
//     grows; lo_i per token),
//   - its beam's path: the tokens of earlier depths on the way to it (plen of them, the same count
//     for every beam at a depth),
//   - the first `shared` new tokens of its group (1: the beam's T, which every Q follows; 0 at
//     depth 0 and for the greedy search) and itself,
//
// and to nothing else: never to other beams' tokens, which the torch path (one SDPA call over the
// context and the whole tree with a mask) computes and throws away.  At depth 16 on a context of
// 400 tokens that path scores each token against ~1,300 keys of which ~400 are visible
// (BENCHMARKS.md, "DICP planning against its floor").
//
// Layout and work split: one (batch, key/value head) at a time.  The context's keys and values
// come transposed, (d, Lp) per (batch, head), prepared once per planned step and read by every
// depth and layer.  Each beam carries its path's keys and values, transposed, in a (d, Pc) buffer
// of its own (`dst`): a call first builds it from the beam's parent in the previous depth's
// buffers (`src`: the parent's path, its shared tokens and the one new token the beam continues
// with, contiguous row copies) and appends the group's new keys and values, so a path is never
// gathered token by token (a scalar gather of the path per beam and call cost ~25 % of the kernel,
// measured).  A query row's scores are computed vectorised across keys into an L1 row buffer
// (context, then path), its maximum taken, then exp and the value sums in a second pass: the
// training kernel's forward (train_attention.cpp) without dropout and log-sum-exp, over two key
// sets.
//
// Build: lhf_hf/modeling/tree_attention.py (g++ -O3 -march=native, cached per machine).  The torch
// reference of the same function: tree_attention.reference.

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "simd.h"  // VW, vf/vi, vload/vstore/vset, hsum/hmax/hsums, vexp

extern "C" {

struct TreeArgs {  // mirrored by ctypes in tree_attention.py (same field order)
  int64_t B, H, Hkv, D;  // batch, query heads, key/value heads, head dim
  int64_t L0, Lp;  // context keys, the row stride of the transposed context (>= L0)
  int64_t n, nb, per_beam, shared;  // new tokens (nb groups of per_beam, beam-major)
  int64_t beams, Pc;  // beam slots and columns of each path buffer
  int64_t plen;  // path length: a beam copies plen - 1 columns from its parent, then one more
  // element strides (batch, token, head) of q, k, v and out; d contiguous
  int64_t q_s[3], k_s[3], v_s[3], o_s[3];
  const float *q;  // (B, n, H, d): the new tokens' queries, RoPE applied, not scaled
  const float *k, *v;  // (B, n, Hkv, d): their keys (RoPE applied) and values
  const float *kct, *vct;  // (B, Hkv, d, Lp): the context's keys and values, transposed
  // path buffers (B, Hkv, beams, d, Pc), transposed: the previous depth's (src; null at the
  // first depth) and this one's (dst, written here)
  const float *src_k, *src_v;
  float *dst_k, *dst_v;
  // (B, nb): each beam's parent in src and the src column of the token it continues with
  const int32_t *parent, *src_col;
  const int32_t* ctx_lo;  // (n,): the first context key each new token sees
  float* o;  // (B, n, H, d)
  float scale;  // applied to q k^T
};

int lhf_tree_abi_version() { return 2; }

}  // extern "C"

namespace {

// One query row (scaled query q) against the context's keys [lo, L0) and the gathered keys
// [0, seen) and `self`: its output, out[0, D).  Scores go to `row` (the context's, then from Lp
// the gathered keys'); the masks are applied only where a vector of keys straddles the range.
template <int D>
void row_attention(const float (&q)[D], int64_t lo, int32_t seen, int32_t self,
                   const float* __restrict kct, const float* __restrict vct, int64_t L0,
                   int64_t Lp, const float* __restrict pkt, const float* __restrict pvt,
                   int64_t np, int64_t Pp, float* __restrict row, float* out) {
  const vi lanes = iota();
  const int64_t j0 = lo / VW * VW;
  vf m = vset(-INFINITY);
  for (int64_t jb = j0; jb < L0; jb += VW) {
    vf s = vset(q[0]) * vload(kct + jb);
    for (int c = 1; c < D; ++c) s += vset(q[c]) * vload(kct + c * Lp + jb);
    if (jb < lo || jb + VW > L0) {
      const vi jj = lanes + static_cast<int32_t>(jb);
      s = (jj >= static_cast<int32_t>(lo)) & (jj < static_cast<int32_t>(L0)) ? s
                                                                             : vset(-INFINITY);
    }
    vstore(row + jb, s);
    m = m > s ? m : s;
  }
  for (int64_t pb = 0; pb < np; pb += VW) {
    vf s = vset(q[0]) * vload(pkt + pb);
    for (int c = 1; c < D; ++c) s += vset(q[c]) * vload(pkt + c * Pp + pb);
    const vi jj = lanes + static_cast<int32_t>(pb);
    s = (jj < seen) | (jj == self) ? s : vset(-INFINITY);
    vstore(row + Lp + pb, s);
    m = m > s ? m : s;
  }
  const vf mx = vset(hmax(m));
  vf acc[D + 1];  // D value sums, then the sum of P (the row's normaliser)
  for (int c = 0; c <= D; ++c) acc[c] = vset(0.f);
  // masked scores are -inf: their exp is 0, so this pass needs no masks
  for (int64_t jb = j0; jb < L0; jb += VW) {
    const vf p = vexp(vload(row + jb) - mx);
    acc[D] += p;
    for (int c = 0; c < D; ++c) acc[c] += p * vload(vct + c * Lp + jb);
  }
  for (int64_t pb = 0; pb < np; pb += VW) {
    const vf p = vexp(vload(row + Lp + pb) - mx);
    acc[D] += p;
    for (int c = 0; c < D; ++c) acc[c] += p * vload(pvt + c * Pp + pb);
  }
  const float inv = 1.f / hsum(acc[D]);
  float sums[D];
  hsums<D>(acc, sums);
  for (int c = 0; c < D; ++c) out[c] = sums[c] * inv;
}

// Builds beam j's path buffer (parent's path and chosen token, then the group's new keys and
// values) and returns its number of columns.
template <int D>
int64_t build_path(const TreeArgs* a, int64_t b, int64_t kvh, int64_t j, float* pk, float* pv) {
  const int64_t u = b * a->Hkv + kvh, Pc = a->Pc, plen = a->plen, per = a->per_beam;
  if (plen > 0) {
    const int64_t par = a->parent[b * a->nb + j], col = a->src_col[b * a->nb + j];
    const float* sk = a->src_k + (u * a->beams + par) * D * Pc;
    const float* sv = a->src_v + (u * a->beams + par) * D * Pc;
    for (int c = 0; c < D; ++c) {
      std::memcpy(pk + c * Pc, sk + c * Pc, (plen - 1) * sizeof(float));
      std::memcpy(pv + c * Pc, sv + c * Pc, (plen - 1) * sizeof(float));
      pk[c * Pc + plen - 1] = sk[c * Pc + col];
      pv[c * Pc + plen - 1] = sv[c * Pc + col];
    }
  }
  for (int64_t t = 0; t < per; ++t) {
    const int64_t i = j * per + t;
    const float* kn = a->k + b * a->k_s[0] + i * a->k_s[1] + kvh * a->k_s[2];
    const float* vn = a->v + b * a->v_s[0] + i * a->v_s[1] + kvh * a->v_s[2];
    for (int c = 0; c < D; ++c) {
      pk[c * Pc + plen + t] = kn[c];
      pv[c * Pc + plen + t] = vn[c];
    }
  }
  // the last vector's columns past np are read, their scores masked to -inf (whatever the keys)
  // and their weights 0: the values there must be finite (0 * NaN is NaN), the buffers are not
  // initialised
  const int64_t np = plen + per, end = (np + VW - 1) / VW * VW;
  for (int c = 0; c < D; ++c)
    for (int64_t t = np; t < end; ++t) pv[c * Pc + t] = 0.f;
  return np;
}

template <int D>
void unit(const TreeArgs* a, int64_t u, float* row) {
  const int64_t Hkv = a->Hkv, b = u / Hkv, kvh = u % Hkv, G = a->H / Hkv;
  const int64_t plen = a->plen, per = a->per_beam, Pc = a->Pc;
  const float* kct = a->kct + u * D * a->Lp;
  const float* vct = a->vct + u * D * a->Lp;
  for (int64_t j = 0; j < a->nb; ++j) {
    float* pk = a->dst_k + (u * a->beams + j) * D * Pc;
    float* pv = a->dst_v + (u * a->beams + j) * D * Pc;
    const int64_t np = build_path<D>(a, b, kvh, j, pk, pv);
    for (int64_t t = 0; t < per; ++t) {
      const int64_t i = j * per + t;
      // path columns this token sees: the path and the group's shared tokens, then itself
      const int32_t seen = static_cast<int32_t>(plen + (t < a->shared ? t : a->shared));
      for (int64_t h = kvh * G; h < (kvh + 1) * G; ++h) {  // the query heads of this key head
        const float* src = a->q + b * a->q_s[0] + i * a->q_s[1] + h * a->q_s[2];
        float q[D];
        for (int c = 0; c < D; ++c) q[c] = src[c] * a->scale;
        row_attention<D>(q, a->ctx_lo[i], seen, static_cast<int32_t>(plen + t), kct, vct, a->L0,
                         a->Lp, pk, pv, np, Pc, row,
                         a->o + b * a->o_s[0] + i * a->o_s[1] + h * a->o_s[2]);
      }
    }
  }
}

template <int D>
int run(const TreeArgs* a, int64_t u0, int64_t u1) {
  // one row of scores: the context's, then the path's
  float* row = static_cast<float*>(std::aligned_alloc(64, (a->Lp + a->Pc) * sizeof(float)));
  if (!row) return 2;
  for (int64_t u = u0; u < u1; ++u) unit<D>(a, u, row);
  std::free(row);
  return 0;
}

int check(const TreeArgs* a, int64_t u0, int64_t u1) {
  if (a->B < 1 || a->Hkv < 1 || a->H % a->Hkv != 0 || u0 < 0 || u1 > a->B * a->Hkv || u0 > u1)
    return 1;
  if (a->L0 < 0 || a->Lp < a->L0 || a->Lp % VW != 0 || a->nb < 1 || a->nb > a->beams ||
      a->per_beam < 1 || a->n != a->nb * a->per_beam || a->shared < 0 ||
      a->shared >= a->per_beam || a->plen < 0 || a->Pc % VW != 0 ||
      a->plen + a->per_beam > a->Pc || a->L0 + a->Pc > 46340)
    return 1;
  if (a->plen > 0 && (!a->src_k || !a->src_v || !a->parent || !a->src_col)) return 1;
  for (int64_t i = 0; i < a->n; ++i)
    if (a->ctx_lo[i] < 0 || a->ctx_lo[i] > a->L0) return 3;
  if (a->plen > 0)
    for (int64_t b = u0 / a->Hkv; u1 > u0 && b <= (u1 - 1) / a->Hkv; ++b)
      for (int64_t j = 0; j < a->nb; ++j) {
        const int32_t par = a->parent[b * a->nb + j], col = a->src_col[b * a->nb + j];
        if (par < 0 || par >= a->beams || col < a->plen - 1 || col >= a->Pc) return 3;
      }
  return 0;
}

}  // namespace

extern "C" {

// Units [u0, u1) of B * Hkv (index b * Hkv + kvh): the output rows of the query heads of kvh.
int lhf_tree_forward(const TreeArgs* a, int64_t u0, int64_t u1) {
  const int code = check(a, u0, u1);
  if (code != 0) return code;
  switch (a->D) {
    case 8: return run<8>(a, u0, u1);
    case 16: return run<16>(a, u0, u1);
    default: return 4;
  }
}

int lhf_tree_vector_width() { return VW; }

}  // extern "C"
