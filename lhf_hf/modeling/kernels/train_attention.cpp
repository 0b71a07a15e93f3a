// Training attention for small head dimensions, forward and backward, with the dropout mask drawn
// from a counter-based hash (never stored):
//
//     P = softmax(scale * Q K^T over the allowed keys);  O = (P * Z) V,  Z = keep / (1 - p)
//
// Why a kernel (BENCHMARKS.md, "Training near the FLOP floor"): with head dimension 8 a score costs
// 16 FLOP, so torch's path (batched matmuls at ~11 GFLOP/s, softmax, dropout mask, elementwise
// products, each a trip of the whole (L, L) tensor through memory) spent ~70 % of an AD step at
// context 200 in attention.  Here one (batch, head) at a time: K and V are transposed into
// (d, L) buffers (L1: 2 x 8 x 400 floats at DICP's 400 tokens), and every query row is computed
// start to end over its allowed keys, vectorised across keys, the row's scores in an L1 buffer.
// Nothing of size (L, L) is ever written.  Flash-attention style, the forward saves only each row's
// log-sum-exp; the backward recomputes P from it and redraws the same dropout mask.
//
// Allowed keys: query i attends to keys [lo_i, hi_i) (causal: [0, i + 1); the band mask of
// lhf_hf.modeling.attention: a window ending at i); tiles outside the range are never computed.
//
// Dropout: element (b, h, i, j) of a call is kept iff hash(i * L + j; key(seed, b * H + h)) >=
// threshold (32-bit, threshold = round(p 2^32)), so the mask depends only on the call's seed (drawn
// by the Python side from torch's generator) and the element's coordinates: not on threads, tiles
// or the order of work, and the backward redraws it exactly.  The hash is a keyed variant of
// Chris Wellons' "lowbias32" integer mixer (two multiply-xorshift rounds, the second keyed), not a
// cryptographic or Philox stream: good enough for a dropout mask (tests check its keep rate, and
// that heads, rows and seeds are uncorrelated), at ~8 vector ops per 16 weights.
//
// Tried and dropped: the backward over blocks of 2 or 4 query rows (sharing the loads of K^T, V^T
// and the read-modify-write of dK^T, dV^T): 4-19 % more CPU time per score than one row at a time
// (register pressure: D accumulators and 2 D broadcasts per row), BENCHMARKS.md.
//
// Build: lhf_hf/modeling/attention_kernel.py (g++ -O3 -march=native, cached per machine, like the
// PPO kernel).  The torch reference: lhf_hf/modeling/train_attention.py (DropoutAttention).

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "simd.h"  // VW, vf/vi/vu, vload/vstore/vset, hsum/hmax/hsums, vexp

namespace {

inline uint64_t splitmix64(uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

struct Key {
  uint32_t k1, k2;
};
inline Key head_key(uint64_t seed, int64_t bh) {
  const uint64_t z = splitmix64(seed ^ splitmix64(static_cast<uint64_t>(bh)));
  return {static_cast<uint32_t>(z), static_cast<uint32_t>(z >> 32)};
}
// 32 random bits per element index (i * L + j) under a head's key.
inline vu vhash(vu x, Key k) {
  x ^= k.k1;
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x ^= k.k2;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}

}  // namespace

extern "C" {

struct AttnArgs {  // mirrored by ctypes in attention_kernel.py (same field order)
  int64_t B, H, L, D;
  // element strides (batch, head, position) of each (B, H, L, D) tensor; D is contiguous
  int64_t q_s[3], k_s[3], v_s[3], o_s[3], do_s[3], dq_s[3], dk_s[3], dv_s[3];
  const float *q, *k, *v;
  float* o;  // forward output (the dropped-out product), read by the backward
  float* lse;  // (B, H, L) row log-sum-exp (-inf for a row without keys)
  const float* dout;
  float *dq, *dk, *dv;
  const int32_t *lo, *hi;  // (L,) query i attends to keys [lo[i], hi[i])
  float scale;  // applied to Q K^T
  float keep_scale;  // 1 / (1 - p)
  uint32_t threshold;  // kept iff hash >= threshold; 0: no dropout
  uint64_t seed;
};

int lhf_attn_abi_version() { return 1; }
int lhf_attn_vector_width() { return VW; }

}  // extern "C"

namespace {

// Per-call scratch: K^T, V^T and (backward) dK^T, dV^T as (D, Lp) plus one row of scores.
struct Scratch {
  float* buf = nullptr;
  float *kt, *vt, *dkt, *dvt, *row;
  bool init(int64_t D, int64_t Lp) {
    const int64_t floats = (4 * D + 1) * Lp;
    buf = static_cast<float*>(std::aligned_alloc(64, ((floats * 4 + 63) / 64) * 64));
    if (!buf) return false;
    kt = buf, vt = kt + D * Lp, dkt = vt + D * Lp, dvt = dkt + D * Lp, row = dvt + D * Lp;
    return true;
  }
  ~Scratch() { std::free(buf); }
};

template <int D>
void load_transposed(const float* x, const int64_t* s, int64_t b, int64_t h, int64_t L,
                     int64_t Lp, float* xt) {
  const float* base = x + b * s[0] + h * s[1];
  for (int64_t j = 0; j < L; ++j)
    for (int c = 0; c < D; ++c) xt[c * Lp + j] = base[j * s[2] + c];
  for (int c = 0; c < D; ++c)
    for (int64_t j = L; j < Lp; ++j) xt[c * Lp + j] = 0.f;
}

template <int D>
void forward_head(const AttnArgs* a, int64_t bh, Scratch& w, int64_t Lp) {
  const int64_t H = a->H, L = a->L, b = bh / H, h = bh % H;
  load_transposed<D>(a->k, a->k_s, b, h, L, Lp, w.kt);
  load_transposed<D>(a->v, a->v_s, b, h, L, Lp, w.vt);
  const float* qb = a->q + b * a->q_s[0] + h * a->q_s[1];
  float* ob = a->o + b * a->o_s[0] + h * a->o_s[1];
  float* lse = a->lse + bh * L;
  const Key key = head_key(a->seed, bh);
  const bool dropout = a->threshold != 0;
  const vu thr = vsetu(a->threshold);
  const vi lanes = iota();
  // locals, so that the compiler keeps them in registers across the stores below
  const float* __restrict kt = w.kt;
  const float* __restrict vt = w.vt;
  float* __restrict row = w.row;
  const int64_t q_l = a->q_s[2], o_l = a->o_s[2];
  const float scale = a->scale, keep_scale = dropout ? a->keep_scale : 1.f;
  for (int64_t i = 0; i < L; ++i) {
    const int64_t lo = a->lo[i], hi = a->hi[i];
    float* oi = ob + i * o_l;
    if (lo >= hi) {  // no key: 0, as SDPA gives a fully masked row
      for (int c = 0; c < D; ++c) oi[c] = 0.f;
      lse[i] = -INFINITY;
      continue;
    }
    vf qi[D];
    for (int c = 0; c < D; ++c) qi[c] = vset(qb[i * q_l + c] * scale);
    const int64_t j0 = lo / VW * VW;
    vf m = vset(-INFINITY);
    for (int64_t jb = j0; jb < hi; jb += VW) {
      vf s = qi[0] * vload(kt + jb);
      for (int c = 1; c < D; ++c) s += qi[c] * vload(kt + c * Lp + jb);
      const vi j = lanes + static_cast<int32_t>(jb);
      s = (j >= static_cast<int32_t>(lo)) & (j < static_cast<int32_t>(hi)) ? s : vset(-INFINITY);
      vstore(row + jb, s);
      m = m > s ? m : s;
    }
    const float mx = hmax(m);
    vf acc[D + 1];  // D value sums, then the row's sum of P (its normaliser)
    for (int c = 0; c <= D; ++c) acc[c] = vset(0.f);
    const vu idx0 = (vu)(lanes + static_cast<int32_t>(i * L));
    for (int64_t jb = j0; jb < hi; jb += VW) {
      vf p = vexp(vload(row + jb) - mx);
      acc[D] += p;
      if (dropout) {
        const vu bits = vhash(idx0 + static_cast<uint32_t>(jb), key);
        p = bits >= thr ? p : vset(0.f);
      }
      for (int c = 0; c < D; ++c) acc[c] += p * vload(vt + c * Lp + jb);
    }
    const float l = hsum(acc[D]);
    float sums[D];
    hsums<D>(acc, sums);
    const float inv = keep_scale / l;
    for (int c = 0; c < D; ++c) oi[c] = sums[c] * inv;
    lse[i] = mx + std::log(l);
  }
}

template <int D>
void backward_head(const AttnArgs* a, int64_t bh, Scratch& w, int64_t Lp) {
  const int64_t H = a->H, L = a->L, b = bh / H, h = bh % H;
  load_transposed<D>(a->k, a->k_s, b, h, L, Lp, w.kt);
  load_transposed<D>(a->v, a->v_s, b, h, L, Lp, w.vt);
  std::memset(w.dkt, 0, 2 * D * Lp * sizeof(float));  // dkt and dvt are adjacent
  const float* qb = a->q + b * a->q_s[0] + h * a->q_s[1];
  const float* ob = a->o + b * a->o_s[0] + h * a->o_s[1];
  const float* dob = a->dout + b * a->do_s[0] + h * a->do_s[1];
  float* dqb = a->dq + b * a->dq_s[0] + h * a->dq_s[1];
  const float* lse = a->lse + bh * L;
  const Key key = head_key(a->seed, bh);
  const bool dropout = a->threshold != 0;
  const float z = dropout ? a->keep_scale : 1.f;
  const vu thr = vsetu(a->threshold);
  const vi lanes = iota();
  const float* __restrict kt = w.kt;
  const float* __restrict vt = w.vt;
  float* __restrict dkt = w.dkt;
  float* __restrict dvt = w.dvt;
  const float scale = a->scale;
  for (int64_t i = 0; i < L; ++i) {
    const int64_t lo = a->lo[i], hi = a->hi[i];
    float* dqi = dqb + i * a->dq_s[2];
    if (lo >= hi) {
      for (int c = 0; c < D; ++c) dqi[c] = 0.f;
      continue;
    }
    float qs[D], dos[D];
    float drow = 0.f;  // dO_i . O_i = sum_j dP_ij P_ij (FlashAttention's identity)
    for (int c = 0; c < D; ++c) {
      qs[c] = qb[i * a->q_s[2] + c] * scale;
      dos[c] = dob[i * a->do_s[2] + c];
      drow += dos[c] * ob[i * a->o_s[2] + c];
    }
    vf acc[D];
    for (int c = 0; c < D; ++c) acc[c] = vset(0.f);
    const vf l = vset(lse[i]), dr = vset(drow);
    const vu idx0 = (vu)(lanes + static_cast<int32_t>(i * L));
    for (int64_t jb = lo / VW * VW; jb < hi; jb += VW) {
      vf s = vset(qs[0]) * vload(kt + jb), dp = vset(dos[0]) * vload(vt + jb);
      for (int c = 1; c < D; ++c) {
        s += vset(qs[c]) * vload(kt + c * Lp + jb);
        dp += vset(dos[c]) * vload(vt + c * Lp + jb);
      }
      const vi j = lanes + static_cast<int32_t>(jb);
      vf p = vexp(s - l);
      p = (j >= static_cast<int32_t>(lo)) & (j < static_cast<int32_t>(hi)) ? p : vset(0.f);
      vf zj = vset(z);  // Z_ij: 1 / (1 - p) where kept, 0 where dropped
      if (dropout) {
        const vu bits = vhash(idx0 + static_cast<uint32_t>(jb), key);
        zj = bits >= thr ? zj : vset(0.f);
      }
      const vf pz = p * zj;  // the weight O used
      const vf ds = p * (dp * zj - dr);  // dS = P (dP Z - rowsum)
      for (int c = 0; c < D; ++c) {
        acc[c] += ds * vload(kt + c * Lp + jb);
        vstore(dkt + c * Lp + jb, vload(dkt + c * Lp + jb) + ds * qs[c]);
        vstore(dvt + c * Lp + jb, vload(dvt + c * Lp + jb) + pz * dos[c]);
      }
    }
    float sums[D];
    hsums<D>(acc, sums);
    for (int c = 0; c < D; ++c) dqi[c] = sums[c] * scale;
  }
  float* dkb = a->dk + b * a->dk_s[0] + h * a->dk_s[1];
  float* dvb = a->dv + b * a->dv_s[0] + h * a->dv_s[1];
  for (int64_t j = 0; j < L; ++j)
    for (int c = 0; c < D; ++c) {
      dkb[j * a->dk_s[2] + c] = w.dkt[c * Lp + j];
      dvb[j * a->dv_s[2] + c] = w.dvt[c * Lp + j];
    }
}

template <int D>
int run(const AttnArgs* a, int64_t bh0, int64_t bh1, bool backward) {
  const int64_t Lp = (a->L + VW - 1) / VW * VW;
  Scratch w;
  if (!w.init(D, Lp)) return 2;
  for (int64_t bh = bh0; bh < bh1; ++bh) {
    if (backward)
      backward_head<D>(a, bh, w, Lp);
    else
      forward_head<D>(a, bh, w, Lp);
  }
  return 0;
}

int dispatch(const AttnArgs* a, int64_t bh0, int64_t bh1, bool backward) {
  if (bh0 < 0 || bh1 > a->B * a->H || bh0 > bh1 || a->L < 1 || a->L > 46340) return 1;
  for (int64_t i = 0; i < a->L; ++i)
    if (a->lo[i] < 0 || a->hi[i] > a->L) return 3;
  switch (a->D) {
    case 8: return run<8>(a, bh0, bh1, backward);
    case 16: return run<16>(a, bh0, bh1, backward);
    default: return 4;
  }
}

}  // namespace

extern "C" {

// Heads [bh0, bh1) of B * H (index b * H + h): O and lse from Q, K, V.
int lhf_attn_forward(const AttnArgs* a, int64_t bh0, int64_t bh1) {
  return dispatch(a, bh0, bh1, false);
}

// Heads [bh0, bh1): dQ, dK, dV from Q, K, V, O, lse and dO.
int lhf_attn_backward(const AttnArgs* a, int64_t bh0, int64_t bh1) {
  return dispatch(a, bh0, bh1, true);
}

// The call's keep mask as the kernel draws it, (B, H, L, L) bytes (1 = kept), for tests: the
// reference attention run with this mask must give the kernel's outputs and gradients.
void lhf_attn_keep_mask(const AttnArgs* a, uint8_t* out) {
  const int64_t L = a->L;
  const vi lanes = iota();
  for (int64_t bh = 0; bh < a->B * a->H; ++bh) {
    const Key key = head_key(a->seed, bh);
    for (int64_t i = 0; i < L; ++i)
      for (int64_t jb = 0; jb < L; jb += VW) {
        const vu bits = vhash((vu)(lanes + static_cast<int32_t>(i * L + jb)), key);
        for (int t = 0; t < VW && jb + t < L; ++t)
          out[(bh * L + i) * L + jb + t] = bits[t] >= a->threshold;
      }
  }
}

// The kernel's exp on n floats (tests check it against float64 exp).
void lhf_attn_exp(const float* x, float* y, int64_t n) {
  int64_t j = 0;
  for (; j + VW <= n; j += VW) vstore(y + j, vexp(vload(x + j)));
  if (j < n) {
    float tail[VW] = {};
    std::memcpy(tail, x + j, (n - j) * sizeof(float));
    const vf t = vexp(vload(tail));
    for (int64_t k = 0; k < n - j; ++k) y[j + k] = t[k];
  }
}

}  // extern "C"
