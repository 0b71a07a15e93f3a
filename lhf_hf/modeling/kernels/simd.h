// Vector helpers shared by the C++ attention kernels (train_attention.cpp, tree_attention.cpp):
// GCC vector types of one register (zmm with AVX-512, ymm with AVX2), loads and stores, broadcasts,
// horizontal sums and maxima, and an exp for x <= 0.  Header-only, everything inline, in an
// anonymous namespace: each kernel library gets its own copy.  lhf_hf/utils/native_build.py hashes
// the text of the local headers a kernel includes into its build key, so editing this file rebuilds
// every kernel that uses it.

#pragma once

#include <cstdint>
#include <cstring>

#include <immintrin.h>

namespace {

#if defined(__AVX512F__)
constexpr int VW = 16;  // floats per vector: one zmm register
#else
constexpr int VW = 8;  // one ymm register (AVX2); plain SSE builds split it, correct but slow
#endif

typedef float vf __attribute__((vector_size(VW * sizeof(float))));
typedef int32_t vi __attribute__((vector_size(VW * sizeof(int32_t))));
typedef uint32_t vu __attribute__((vector_size(VW * sizeof(uint32_t))));

inline vf vload(const float* p) { vf v; std::memcpy(&v, p, sizeof v); return v; }
inline void vstore(float* p, vf v) { std::memcpy(p, &v, sizeof v); }
// A broadcast, not `vf{} + x` (a real addition, compiled to a scalar add and a shuffle).
inline vf vset(float x) {
#if defined(__AVX512F__)
  return (vf)_mm512_set1_ps(x);
#elif defined(__AVX__)
  return (vf)_mm256_set1_ps(x);
#else
  vf v;
  for (int j = 0; j < VW; ++j) v[j] = x;
  return v;
#endif
}
inline vu vsetu(uint32_t x) {
  vu v;
  for (int j = 0; j < VW; ++j) v[j] = x;
  return v;
}
inline vi iota() {
  vi v;
  for (int j = 0; j < VW; ++j) v[j] = j;
  return v;
}
inline float hsum(vf v) {  // tree: log2(VW) shuffle + add levels
#if defined(__AVX512F__)
  v += __builtin_shuffle(v, vi{8, 9, 10, 11, 12, 13, 14, 15, 0, 1, 2, 3, 4, 5, 6, 7});
  v += __builtin_shuffle(v, vi{4, 5, 6, 7, 0, 1, 2, 3, 12, 13, 14, 15, 8, 9, 10, 11});
  v += __builtin_shuffle(v, vi{2, 3, 0, 1, 6, 7, 4, 5, 10, 11, 8, 9, 14, 15, 12, 13});
  v += __builtin_shuffle(v, vi{1, 0, 3, 2, 5, 4, 7, 6, 9, 8, 11, 10, 13, 12, 15, 14});
#else
  v += __builtin_shuffle(v, vi{4, 5, 6, 7, 0, 1, 2, 3});
  v += __builtin_shuffle(v, vi{2, 3, 0, 1, 6, 7, 4, 5});
  v += __builtin_shuffle(v, vi{1, 0, 3, 2, 5, 4, 7, 6});
#endif
  return v[0];
}
inline float hmax(vf v) {  // tree, as hsum
#if defined(__AVX512F__)
  vf u = __builtin_shuffle(v, vi{8, 9, 10, 11, 12, 13, 14, 15, 0, 1, 2, 3, 4, 5, 6, 7});
  v = v > u ? v : u;
  u = __builtin_shuffle(v, vi{4, 5, 6, 7, 0, 1, 2, 3, 12, 13, 14, 15, 8, 9, 10, 11});
  v = v > u ? v : u;
  u = __builtin_shuffle(v, vi{2, 3, 0, 1, 6, 7, 4, 5, 10, 11, 8, 9, 14, 15, 12, 13});
  v = v > u ? v : u;
  u = __builtin_shuffle(v, vi{1, 0, 3, 2, 5, 4, 7, 6, 9, 8, 11, 10, 13, 12, 15, 14});
#else
  vf u = __builtin_shuffle(v, vi{4, 5, 6, 7, 0, 1, 2, 3});
  v = v > u ? v : u;
  u = __builtin_shuffle(v, vi{2, 3, 0, 1, 6, 7, 4, 5});
  v = v > u ? v : u;
  u = __builtin_shuffle(v, vi{1, 0, 3, 2, 5, 4, 7, 6});
#endif
  v = v > u ? v : u;
  return v[0];
}

// fold<G>(a, b): each group of G lanes of a and of b summed in half, a's halves first: lane t of
// the result is the sum of lanes (t / H) G + t % H and that + H of (a, b) side by side, H = G / 2.
// Folding pairs of vectors level by level gives the lane sums of N vectors in ~3 N shuffles and
// adds instead of N trees of 2 log2(VW) (a row of a short context has few keys, so these sums are
// a visible part of its cost).
template <int G>
inline vf fold(vf a, vf b) {
#if defined(__AVX512F__)
  if constexpr (G == 16)
    return __builtin_shuffle(a, b, vi{0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23}) +
           __builtin_shuffle(a, b, vi{8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31});
  if constexpr (G == 8)
    return __builtin_shuffle(a, b, vi{0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 24, 25, 26, 27}) +
           __builtin_shuffle(a, b, vi{4, 5, 6, 7, 12, 13, 14, 15, 20, 21, 22, 23, 28, 29, 30, 31});
  if constexpr (G == 4)
    return __builtin_shuffle(a, b, vi{0, 1, 4, 5, 8, 9, 12, 13, 16, 17, 20, 21, 24, 25, 28, 29}) +
           __builtin_shuffle(a, b, vi{2, 3, 6, 7, 10, 11, 14, 15, 18, 19, 22, 23, 26, 27, 30, 31});
  if constexpr (G == 2)
    return __builtin_shuffle(a, b, vi{0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30}) +
           __builtin_shuffle(a, b, vi{1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31});
#else
  if constexpr (G == 8)
    return __builtin_shuffle(a, b, vi{0, 1, 2, 3, 8, 9, 10, 11}) +
           __builtin_shuffle(a, b, vi{4, 5, 6, 7, 12, 13, 14, 15});
  if constexpr (G == 4)
    return __builtin_shuffle(a, b, vi{0, 1, 4, 5, 8, 9, 12, 13}) +
           __builtin_shuffle(a, b, vi{2, 3, 6, 7, 10, 11, 14, 15});
  if constexpr (G == 2)
    return __builtin_shuffle(a, b, vi{0, 2, 4, 6, 8, 10, 12, 14}) +
           __builtin_shuffle(a, b, vi{1, 3, 5, 7, 9, 11, 13, 15});
#endif
}
// One level: N vectors with groups of G lanes -> N / 2 vectors with groups of G / 2 (N even), or
// one vector folded with itself (N == 1).
template <int N, int G>
inline void fold_level(vf* v) {
  if constexpr (N == 1)
    v[0] = fold<G>(v[0], v[0]);
  else
    for (int k = 0; k < N / 2; ++k) v[k] = fold<G>(v[2 * k], v[2 * k + 1]);
}
template <int N, int G>
inline void fold_all(vf* v) {  // down to groups of one lane
  if constexpr (G > 1) {
    fold_level<N, G>(v);
    fold_all<(N > 1 ? N / 2 : 1), G / 2>(v);
  }
}
// out[c] = the lane sum of in[c], c < N (N a power of 2, <= 2 VW).
template <int N>
inline void hsums(const vf* in, float* out) {
  vf v[N];  // a copy: the callers' accumulators stay in registers
  for (int k = 0; k < N; ++k) v[k] = in[k];
  fold_all<N, VW>(v);
  // log2(VW) levels leave max(N / VW, 1) vectors, each with its sums in order in its first lanes
  constexpr int left = N > VW ? N / VW : 1, per = N / left;
  for (int k = 0; k < left; ++k)
    for (int t = 0; t < per; ++t) out[k * per + t] = v[k][t];
}

// exp(x) for x <= 0 (scores minus their row's maximum or log-sum-exp), ~13 vector ops.
// x = n ln2 + r, |r| <= ln2 / 2, n = round(x / ln2); exp(r) by Cephes' expf polynomial
// (1 + r + r^2 P(r), P of degree 5: relative error ~1e-7 on that interval), times 2^n built in the
// exponent bits.  x < -87.3 (exp below the smallest normal float, and -inf: masked lanes) gives
// exactly 0; tests check the relative error against float64 exp over [-87, 0].
inline vf vexp(vf x) {
  const vf xc = x > -87.3f ? x : vset(-87.3f);
  const vf magic = vset(12582912.f);  // 1.5 * 2^23: adding it rounds to an integer
  const vf t = xc * 1.44269504088896341f + magic;
  const vf n = t - magic;
  vf r = xc - n * 0.693359375f;  // ln 2 in two parts (Cody-Waite): the first is exact in n * c
  r = r - n * -2.12194440e-4f;
  vf p = vset(1.9875691500e-4f);
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * (r * r) + r + 1.f;
  const vi e = (__builtin_convertvector(n, vi) + 127) << 23;  // 2^n, n in [-126, 0]
  vf scale;
  std::memcpy(&scale, &e, sizeof scale);
  const vf y = p * scale;
  return x > -87.3f ? y : vset(0.f);
}

}  // namespace
