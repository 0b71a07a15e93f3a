// Stable-Baselines3's PPO update (PPO.train, MlpPolicy, discrete actions) for many learners, one
// learner at a time, the whole update in L1/L2 cache.
//
// Why a kernel (see BENCHMARKS.md, "Batched PPO collector"): stacked torch ops run every minibatch
// step of L learners as ~60 ops over (2L, b, 64) tensors.  At paper size (64 wide, b = 50..100) each
// op streams megabytes through L3 and pays dispatch and thread start-up; the update reached ~1/4 of
// the machine's batched-matmul FLOP rate.  A learner's whole update (all epochs and minibatches) only
// touches its own ~37 KB of weights, 74 KB of Adam state and its rollout, so here one learner is
// updated from start to end while all of that stays in cache, with register-blocked 64-wide
// matmuls and the bias, tanh and tanh' fused into them.  Learners are independent, so callers split
// [0, L) across threads (the Python side runs one call per thread; ctypes releases the GIL).
//
// The arithmetic is that of lhf_hf.collection.batched_ppo (the torch reference, itself tested
// against SB3): same loss, same hand-derived gradients, per-learner gradient-norm clipping, torch's
// Adam formula.  Differences are float rounding only: sums run in another order, tanh is this file's
// own (max relative error ~1e-7, tested), reductions for norms and advantage statistics run in
// double.  Build: lhf_hf/collection/native.py (g++ -O3 -march=native, cached per machine).

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include <immintrin.h>

#ifndef HID
#define HID 64
#endif

namespace {

constexpr int H = HID;  // hidden width (SB3 MlpPolicy: 64)
// Vector width and register blocking per instruction set, chosen at compile time.  A matmul block
// keeps RB rows x CB vectors of accumulators, the CB vectors of one weight row and one broadcast in
// registers.  AVX-512 (32 zmm registers of 16 floats): 4 x 4 + 4 + 1 = 21.  AVX2 + FMA (16 ymm
// registers of 8 floats): 16-float vectors would be split in two by the compiler, so the same block
// would need 42 registers and spill on every FMA (measured: half the torch path's speed on an AVX2
// CPU, BENCHMARKS.md); 8-float vectors in 6 x 2 blocks need 6 x 2 + 2 + 1 = 15.  Why 6 rows, not
// 4: with 4 x 2 = 8 accumulators, two FMA pipes of latency 4 (AMD Zen 3) have exactly 8 chains in
// flight and any stall shows; 12 chains hide it: a Darkroom minibatch step went from 3.9-4.1 to
// 2.9-3.3 ms on an AMD EPYC (BENCHMARKS.md).  Rows left over (m % RB) run in 4-, 2- and 1-row
// blocks.  Each output element is accumulated over k in the same order either way.
#if defined(__AVX512F__)
constexpr int VW = 16;  // floats per vector: one zmm register
constexpr int RB = 4;   // rows per register block
constexpr int CB = 4;   // vectors per register block (H = 64: a whole row)
#else
constexpr int VW = 8;   // one ymm register (AVX2); plain SSE builds split it, correct but slow
constexpr int RB = 6;
constexpr int CB = 2;
#endif
constexpr int NV = H / VW;  // vectors per hidden row
static_assert(H % 16 == 0, "the hidden width must be a multiple of 16");
static_assert(NV % CB == 0, "a hidden row is a whole number of register blocks");

typedef float vf __attribute__((vector_size(VW * sizeof(float))));
typedef int32_t vi __attribute__((vector_size(VW * sizeof(int32_t))));

inline vf vload(const float* p) { vf v; std::memcpy(&v, p, sizeof v); return v; }
inline void vstore(float* p, vf v) { std::memcpy(p, &v, sizeof v); }
// x in every lane.  Not `vf{} + x`: that is a real addition (0 + -0 is +0), compiled to a scalar add
// and a register broadcast on a port that also runs FMAs (~10% of an update); a broadcast from
// memory is a plain load.
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
inline float hsum(vf v) {  // tree: log2(VW) shuffle + add levels instead of VW - 1 dependent adds
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

// 1 / x and 1 / sqrt(x) for x > 0.  A division or square root of a full vector costs ~10 cycles
// of throughput (they dominated Adam and tanh); the hardware estimates (14 bits) plus one
// Newton-Raphson step cost ~4 cycles and are accurate to a few float ulps.
#if defined(__AVX512F__)  // (VW is 16: one zmm register)
inline vf vrcp(vf x) {
  const vf r = (vf)_mm512_rcp14_ps((__m512)x);
  return r * (2.f - x * r);
}
inline vf vrsqrt(vf x) {
  const vf r = (vf)_mm512_rsqrt14_ps((__m512)x);
  return r * (1.5f - 0.5f * x * r * r);
}
#elif defined(__AVX__)  // (VW is 8: one ymm register; the estimates have 12 bits, so after one
// Newton-Raphson step ~23: within 2 ulps, like the AVX-512 path's)
inline vf vrcp(vf x) {
  const vf r = (vf)_mm256_rcp_ps((__m256)x);
  return r * (2.f - x * r);
}
inline vf vrsqrt(vf x) {
  const vf r = (vf)_mm256_rsqrt_ps((__m256)x);
  return r * (1.5f - 0.5f * x * r * r);
}
#else
inline vf vrcp(vf x) { return 1.f / x; }
inline vf vrsqrt(vf x) {
  vf r;
  for (int j = 0; j < VW; ++j) r[j] = 1.f / std::sqrt(x[j]);
  return r;
}
#endif

// tanh(x) = c P(c^2) / Q(c^2), c = x clamped to [-9, 9] (tanh(9) rounds to 1 in float): a rational
// approximation with P of degree 6 and Q of degree 3 in c^2, fitted here for minimal relative error
// on [0, 9] by scripts/fit_tanh.py (fit error 7e-9).  Evaluated in
// float it is within 3.6e-7 (relative) of tanh for every float (tested); the result is clamped to
// [-1, 1] since rounding can lift it 2 ulps above 1.  ~17 vector ops: the former polynomial + exp
// form (~38) was ~16% of an update (BENCHMARKS.md, "Batched PPO collector").
inline vf vtanh(vf x) {
  vf c = x < 9.f ? x : vset(9.f);
  c = c > -9.f ? c : vset(-9.f);
  const vf t = c * c;
  vf p = vset(-8.489348411527473e-14f);
  p = p * t + 5.278225079230481e-11f;
  p = p * t - 2.0225863650580322e-08f;
  p = p * t + 1.1154479580000043e-05f;
  p = p * t + 0.003103973576799035f;
  p = p * t + 0.1308402568101883f;
  p = p * t + 1.f;
  vf q = vset(0.00025461698533035815f);
  q = q * t + 0.02449524775147438f;
  q = q * t + 0.4641735255718231f;
  q = q * t + 1.f;
  vf r = c * p * vrcp(q);
  r = r < 1.f ? r : vset(1.f);
  return r > -1.f ? r : vset(-1.f);
}

// out (H, H) = in^T, by VW x VW blocks, each transposed in registers in log2(VW) stages of two-input
// shuffles (stage g swaps the off-diagonal g x g sub-blocks); a scalar loop took ~2 us per call.
void transpose(const float* in, float* out) {
  for (int bi = 0; bi < H; bi += VW)
    for (int bj = 0; bj < H; bj += VW) {
      vf r[VW];
      for (int i = 0; i < VW; ++i) r[i] = vload(in + (bi + i) * H + bj);
#define LHF_STAGE(g, LO, HI)                                 \
  for (int i = 0; i < VW; ++i)                               \
    if ((i & g) == 0) {                                      \
      const vf a = r[i], b = r[i + g];                       \
      r[i] = __builtin_shuffle(a, b, LO);                    \
      r[i + g] = __builtin_shuffle(a, b, HI);                \
    }
#if defined(__AVX512F__)
      LHF_STAGE(8, (vi{0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23}),
                (vi{8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31}))
      LHF_STAGE(4, (vi{0, 1, 2, 3, 16, 17, 18, 19, 8, 9, 10, 11, 24, 25, 26, 27}),
                (vi{4, 5, 6, 7, 20, 21, 22, 23, 12, 13, 14, 15, 28, 29, 30, 31}))
      LHF_STAGE(2, (vi{0, 1, 16, 17, 4, 5, 20, 21, 8, 9, 24, 25, 12, 13, 28, 29}),
                (vi{2, 3, 18, 19, 6, 7, 22, 23, 10, 11, 26, 27, 14, 15, 30, 31}))
      LHF_STAGE(1, (vi{0, 16, 2, 18, 4, 20, 6, 22, 8, 24, 10, 26, 12, 28, 14, 30}),
                (vi{1, 17, 3, 19, 5, 21, 7, 23, 9, 25, 11, 27, 13, 29, 15, 31}))
#else
      LHF_STAGE(4, (vi{0, 1, 2, 3, 8, 9, 10, 11}), (vi{4, 5, 6, 7, 12, 13, 14, 15}))
      LHF_STAGE(2, (vi{0, 1, 8, 9, 4, 5, 12, 13}), (vi{2, 3, 10, 11, 6, 7, 14, 15}))
      LHF_STAGE(1, (vi{0, 8, 2, 10, 4, 12, 6, 14}), (vi{1, 9, 3, 11, 5, 13, 7, 15}))
#endif
#undef LHF_STAGE
      for (int i = 0; i < VW; ++i) vstore(out + (bj + i) * H + bi, r[i]);
    }
}

enum Epilogue { NONE, TANH, DTANH };

// c[r, cols] = epilogue(bias + a[r, :] @ B[:, cols]) for RB_ rows and the CB vectors of columns
// from col0; a (rows, H), B (H, H) row-major.
// TANH: c = tanh(.); DTANH: c = (.) * (1 - y^2) with y the forward's tanh output (tanh').
template <int RB_, Epilogue EP, bool BIAS>
inline void mm_block(const float* a, const float* B, const float* bias, const float* y, float* c,
                     int col0) {
  vf acc[RB_][CB];
  for (int r = 0; r < RB_; ++r)
    for (int v = 0; v < CB; ++v) acc[r][v] = BIAS ? vload(bias + col0 + v * VW) : vf{};
  for (int k = 0; k < H; ++k) {
    vf w[CB];
    for (int v = 0; v < CB; ++v) w[v] = vload(B + k * H + col0 + v * VW);
    for (int r = 0; r < RB_; ++r) {
      const vf s = vset(a[r * H + k]);
      for (int v = 0; v < CB; ++v) acc[r][v] += s * w[v];
    }
  }
  for (int r = 0; r < RB_; ++r)
    for (int v = 0; v < CB; ++v) {
      vf o = acc[r][v];
      if (EP == TANH) o = vtanh(o);
      if (EP == DTANH) {
        const vf yy = vload(y + r * H + col0 + v * VW);
        o = o * (1.f - yy * yy);
      }
      vstore(c + r * H + col0 + v * VW, o);
    }
}

// C (m, H) = epilogue(bias + A (m, H) @ B (H, H))
template <Epilogue EP, bool BIAS>
void mm_nn(int m, const float* a, const float* B, const float* bias, const float* y, float* c) {
  for (int col0 = 0; col0 < H; col0 += CB * VW) {
    int i = 0;
    for (; i + RB <= m; i += RB)
      mm_block<RB, EP, BIAS>(a + i * H, B, bias, y + i * H, c + i * H, col0);
    if (RB > 4 && i + 4 <= m) {
      mm_block<4, EP, BIAS>(a + i * H, B, bias, y + i * H, c + i * H, col0);
      i += 4;
    }
    if (RB > 2 && i + 2 <= m) {
      mm_block<2, EP, BIAS>(a + i * H, B, bias, y + i * H, c + i * H, col0);
      i += 2;
    }
    for (; i < m; ++i) mm_block<1, EP, BIAS>(a + i * H, B, bias, y + i * H, c + i * H, col0);
  }
}

// g[k .. k + RB_, cols] = A[:, k .. k + RB_]^T @ D[:, cols] for the CB vectors of columns from col0.
template <int RB_>
inline void mm_tn_block(int m, const float* a, const float* d, float* g, int k, int col0) {
  vf acc[RB_][CB] = {};
  for (int i = 0; i < m; ++i) {
    vf dv[CB];
    for (int v = 0; v < CB; ++v) dv[v] = vload(d + i * H + col0 + v * VW);
    for (int r = 0; r < RB_; ++r) {
      const vf s = vset(a[i * H + k + r]);
      for (int v = 0; v < CB; ++v) acc[r][v] += s * dv[v];
    }
  }
  for (int r = 0; r < RB_; ++r)
    for (int v = 0; v < CB; ++v) vstore(g + (k + r) * H + col0 + v * VW, acc[r][v]);
}

// G (H, H) = A^T (H, m) @ D (m, H), and gb (H) = column sums of D: the weight and bias gradients.
void mm_tn(int m, const float* a, const float* d, float* g, float* gb) {
  for (int col0 = 0; col0 < H; col0 += CB * VW) {
    int k = 0;
    for (; k + RB <= H; k += RB) mm_tn_block<RB>(m, a, d, g, k, col0);
    for (; k < H; k += 4) mm_tn_block<4>(m, a, d, g, k, col0);  // H % 4 == 0
  }
  vf sb[NV] = {};
  for (int i = 0; i < m; ++i)
    for (int v = 0; v < NV; ++v) sb[v] += vload(d + i * H + v * VW);
  for (int v = 0; v < NV; ++v) vstore(gb + v * VW, sb[v]);
}
static_assert((H % RB) % 4 == 0, "mm_tn blocks the hidden rows by RB, then by 4");

}  // namespace

extern "C" {

// Mirrored by ctypes in lhf_hf/collection/native.py: keep the two in the same order.
struct PPOArgs {
  int64_t L, N, d, A, batch, n_epochs;
  // Stacked SB3 nets, rows [0, L) actors, [L, 2L) critics (critic heads padded to A columns):
  // 0 W1 (2L, d, H), 1 B1 (2L, 1, H), 2 W2 (2L, H, H), 3 B2 (2L, 1, H), 4 W3 (2L, H, A), 5 B3 (2L, 1, A)
  float* params[6];
  float* exp_avg[6];
  float* exp_avg_sq[6];
  const float* obs;         // (L, N, d)
  const int64_t* actions;   // (L, N)
  const float* old_logp;    // (L, N)
  const float* advantages;  // (L, N)
  const float* returns;     // (L, N)
  const int64_t* perms;     // (n_epochs, L, N) or null: then drawn here from seed
  uint64_t seed;
  double lr, beta1, beta2, eps;
  double step0;  // Adam steps already taken (every learner takes one per minibatch)
  double clip_range, vf_coef, max_grad_norm;
};

int lhf_abi_version() { return 1; }
int lhf_hidden() { return H; }
int lhf_vector_width() { return VW; }  // floats per vector: 16 (AVX-512) or 8 (AVX2), for tests

}  // extern "C"

namespace {

inline uint64_t splitmix64(uint64_t& s) {
  uint64_t z = (s += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

struct Net {  // one net's tensors (weights, Adam moments) and its gradient scratch
  float* p[6];
  float* m[6];
  float* v[6];
  float* g[6];
};

struct Sizes {
  int64_t n[6];  // elements of each tensor per net
};

// One minibatch of one net: forward, loss gradient (actor: clipped surrogate; critic: value loss),
// backward into net.g.  x (m, d); actor: dlogit rows; critic: column 0 of the padded head.
struct Work {
  int d, A;
  float *h1, *h2, *dh1, *dh2, *out, *dout, *w2t, *w3t;
};

void forward(const Net& net, const Work& w, int m, const float* x, int A_used) {
  const int d = w.d, A = w.A;
  const float* W1 = net.p[0];
  const float* B1 = net.p[1];
  for (int i = 0; i < m; ++i)
    for (int v = 0; v < NV; ++v) {
      vf acc = vload(B1 + v * VW);
      for (int k = 0; k < d; ++k) acc += x[i * d + k] * vload(W1 + k * H + v * VW);
      vstore(w.h1 + i * H + v * VW, vtanh(acc));
    }
  mm_nn<TANH, true>(m, w.h1, net.p[2], net.p[3], w.h1, w.h2);  // y unused
  const float* W3 = net.p[4];
  for (int a = 0; a < A_used; ++a)
    for (int k = 0; k < H; ++k) w.w3t[a * H + k] = W3[k * A + a];
  for (int i = 0; i < m; ++i)
    for (int a = 0; a < A_used; ++a) {
      vf acc = vf{};
      for (int v = 0; v < NV; ++v) acc += vload(w.h2 + i * H + v * VW) * vload(w.w3t + a * H + v * VW);
      w.out[i * A + a] = net.p[5][a] + hsum(acc);
    }
}

void backward(const Net& net, const Work& w, int m, const float* x, int A_used) {
  const int d = w.d, A = w.A;
  // layer 3: gW3 (H, A) = h2^T dout, gB3 = sum dout; dh2 = (dout W3^T) * (1 - h2^2)
  float* gW3 = net.g[4];
  float* gB3 = net.g[5];
  for (int a = 0; a < A_used; ++a) {
    vf acc[NV] = {};
    float sb = 0.f;
    for (int i = 0; i < m; ++i) {
      const float g = w.dout[i * A + a];
      sb += g;
      for (int v = 0; v < NV; ++v) acc[v] += g * vload(w.h2 + i * H + v * VW);
    }
    gB3[a] = sb;
    for (int v = 0; v < NV; ++v)
      for (int j = 0; j < VW; ++j) gW3[(v * VW + j) * A + a] = acc[v][j];
  }
  for (int i = 0; i < m; ++i)
    for (int v = 0; v < NV; ++v) {
      vf acc = vf{};
      for (int a = 0; a < A_used; ++a) acc += w.dout[i * A + a] * vload(w.w3t + a * H + v * VW);
      const vf y = vload(w.h2 + i * H + v * VW);
      vstore(w.dh2 + i * H + v * VW, acc * (1.f - y * y));
    }
  // layer 2: gW2 = h1^T dh2, gB2 = sum dh2; dh1 = (dh2 W2^T) * (1 - h1^2)
  mm_tn(m, w.h1, w.dh2, net.g[2], net.g[3]);
  transpose(net.p[2], w.w2t);
  mm_nn<DTANH, false>(m, w.dh2, w.w2t, nullptr, w.h1, w.dh1);
  // layer 1: gW1 (d, H) = x^T dh1, gB1 = sum dh1
  for (int k = 0; k < d; ++k) {
    vf acc[NV] = {};
    for (int i = 0; i < m; ++i)
      for (int v = 0; v < NV; ++v) acc[v] += x[i * d + k] * vload(w.dh1 + i * H + v * VW);
    for (int v = 0; v < NV; ++v) vstore(net.g[0] + k * H + v * VW, acc[v]);
  }
  vf sb[NV] = {};
  for (int i = 0; i < m; ++i)
    for (int v = 0; v < NV; ++v) sb[v] += vload(w.dh1 + i * H + v * VW);
  for (int v = 0; v < NV; ++v) vstore(net.g[1] + v * VW, sb[v]);
}

// e[k] = exp(z[k] - max z) for one row of A logits; *sum = sum_k e[k]; returns max z.  Shared by
// the update's log-softmax gradient and acting's inverse-CDF sampling (each exp computed once).
inline float shifted_exp(const float* z, int64_t A, float* e, float* sum) {
  float mx = z[0];
  for (int64_t k = 1; k < A; ++k) mx = z[k] > mx ? z[k] : mx;
  float s = 0.f;
  for (int64_t k = 0; k < A; ++k) s += (e[k] = std::exp(z[k] - mx));
  *sum = s;
  return mx;
}

// sum of x^2 with four independent vector accumulators (a serial sum is latency-bound: it once
// took a quarter of the whole update)
double sum_squares(const float* x, int64_t n) {
  vf acc[4] = {};
  int64_t j = 0;
  for (; j + 4 * VW <= n; j += 4 * VW)
    for (int u = 0; u < 4; ++u) {
      const vf v = vload(x + j + u * VW);
      acc[u] += v * v;
    }
  double s = static_cast<double>(hsum(acc[0] + acc[1])) + static_cast<double>(hsum(acc[2] + acc[3]));
  for (; j < n; ++j) s += static_cast<double>(x[j]) * x[j];
  return s;
}

struct AdamStep {
  float coef, one_minus_b1, b2, one_minus_b2, inv_bc2_sqrt, eps, step_size;
};

// torch's Adam on g * coef (the clipped gradient): m.lerp_(g, 1 - beta1); v = beta2 v + (1 - beta2)
// g^2; p -= lr / bc1 * m / (sqrt(v) / sqrt(bc2) + eps).  sqrt(v) = v * rsqrt(v) (0 stays 0) and the
// division is a refined reciprocal (see vrcp): same formula, a few ulps from torch's rounding.
void adam(const AdamStep& s, float* p, float* m, float* v, const float* g, int64_t n) {
  int64_t j = 0;
  for (; j + VW <= n; j += VW) {
    const vf gj = vload(g + j) * s.coef;
    vf mj = vload(m + j);
    mj += s.one_minus_b1 * (gj - mj);
    const vf vj = s.b2 * vload(v + j) + s.one_minus_b2 * gj * gj;
    const vf sq = vj * vrsqrt(vj > 1e-30f ? vj : vset(1e-30f));
    vstore(m + j, mj);
    vstore(v + j, vj);
    vstore(p + j, vload(p + j) - s.step_size * mj * vrcp(sq * s.inv_bc2_sqrt + s.eps));
  }
  for (; j < n; ++j) {
    const float gj = g[j] * s.coef;
    const float mj = m[j] + s.one_minus_b1 * (gj - m[j]);
    const float vj = s.b2 * v[j] + s.one_minus_b2 * gj * gj;
    m[j] = mj;
    v[j] = vj;
    p[j] -= s.step_size * mj / (std::sqrt(vj) * s.inv_bc2_sqrt + s.eps);
  }
}

}  // namespace

extern "C" int lhf_ppo_update(const PPOArgs* a, int64_t l0, int64_t l1) {
  const int64_t L = a->L, N = a->N, d = a->d, A = a->A, B = a->batch;
  if (l0 < 0 || l1 > L || l0 > l1 || B < 1 || d < 1 || A < 1 || N < 1) return 1;
  const Sizes sz{{d * H, H, H * H, H, H * A, A}};
  int64_t per_net = 0;
  for (int t = 0; t < 6; ++t) per_net += sz.n[t];
  // scratch: 2 nets' gradients, activations of one minibatch, the minibatch itself, a permutation
  const int64_t floats = 2 * per_net + 4 * B * H + 2 * B * A + H * H + A * H + B * d + 4 * B;
  float* buf = static_cast<float*>(std::aligned_alloc(64, ((floats * 4 + 63) / 64) * 64));
  int64_t* idx = static_cast<int64_t*>(std::malloc(N * sizeof(int64_t)));
  int64_t* act = static_cast<int64_t*>(std::malloc(B * sizeof(int64_t)));
  if (!buf || !idx || !act) {
    std::free(buf);
    std::free(idx);
    std::free(act);
    return 2;
  }
  std::memset(buf, 0, floats * 4);
  float* q = buf;
  auto take = [&q](int64_t n) { float* r = q; q += n; return r; };
  float* grads = take(2 * per_net);
  Work w{static_cast<int>(d), static_cast<int>(A), take(B * H), take(B * H), take(B * H),
         take(B * H), take(B * A), take(B * A), take(H * H), take(A * H)};
  float* x = take(B * d);
  float* adv = take(B);
  float* oldlp = take(B);
  float* ret = take(B);
  float* ratio_g = take(B);

  const float b1 = static_cast<float>(a->beta1), b2 = static_cast<float>(a->beta2);
  const float eps = static_cast<float>(a->eps);
  const float lo = static_cast<float>(1.0 - a->clip_range), hi = static_cast<float>(1.0 + a->clip_range);

  for (int64_t l = l0; l < l1; ++l) {
    Net nets[2];
    for (int n = 0; n < 2; ++n) {
      const int64_t row = n == 0 ? l : L + l;  // actor, critic
      float* g = grads + n * per_net;
      for (int t = 0; t < 6; ++t) {
        nets[n].p[t] = a->params[t] + row * sz.n[t];
        nets[n].m[t] = a->exp_avg[t] + row * sz.n[t];
        nets[n].v[t] = a->exp_avg_sq[t] + row * sz.n[t];
        nets[n].g[t] = g;
        g += sz.n[t];
      }
    }
    const float* obs = a->obs + l * N * d;
    const int64_t* actions = a->actions + l * N;
    double step = a->step0;
    for (int64_t e = 0; e < a->n_epochs; ++e) {
      if (a->perms) {
        std::memcpy(idx, a->perms + (e * L + l) * N, N * sizeof(int64_t));
      } else {  // Fisher-Yates from a stream of (seed, learner, epoch): independent of threading
        uint64_t s = a->seed ^ (0x9E3779B97F4A7C15ull * static_cast<uint64_t>(l + 1));
        s = splitmix64(s) ^ static_cast<uint64_t>(e);
        for (int64_t i = 0; i < N; ++i) idx[i] = i;
        for (int64_t i = N - 1; i > 0; --i) {
          const int64_t j = static_cast<int64_t>(
              (static_cast<unsigned __int128>(splitmix64(s)) * static_cast<uint64_t>(i + 1)) >> 64);
          const int64_t t = idx[i];
          idx[i] = idx[j];
          idx[j] = t;
        }
      }
      for (int64_t start = 0; start < N; start += B) {
        const int m = static_cast<int>(start + B <= N ? B : N - start);
        // gather the minibatch (SB3 indexes the permuted buffer)
        double mean = 0.0;
        for (int i = 0; i < m; ++i) {
          const int64_t s = idx[start + i];
          if (s < 0 || s >= N) {
            std::free(buf);
            std::free(idx);
            std::free(act);
            return 3;
          }
          for (int k = 0; k < d; ++k) x[i * d + k] = obs[s * d + k];
          act[i] = actions[s];
          adv[i] = a->advantages[l * N + s];
          oldlp[i] = a->old_logp[l * N + s];
          ret[i] = a->returns[l * N + s];
          mean += adv[i];
        }
        if (m > 1) {  // SB3 normalises advantages per minibatch, torch.std (unbiased) + 1e-8
          mean /= m;
          double var = 0.0;
          for (int i = 0; i < m; ++i) var += (adv[i] - mean) * (adv[i] - mean);
          const float sd = static_cast<float>(std::sqrt(var / (m - 1)));
          for (int i = 0; i < m; ++i) adv[i] = (adv[i] - static_cast<float>(mean)) / (sd + 1e-8f);
        }
        // actor: d loss / d logits = g_i (onehot(a_i) - softmax_i), g_i = -adv ratio active / m
        forward(nets[0], w, m, x, static_cast<int>(A));
        for (int i = 0; i < m; ++i) {
          const float* z = w.out + i * A;
          float* dz = w.dout + i * A;
          float s;
          const float mx = shifted_exp(z, A, dz, &s);  // dz holds exp(z - max) until overwritten
          const int64_t ai = act[i];
          if (ai < 0 || ai >= A) {
            std::free(buf);
            std::free(idx);
            std::free(act);
            return 4;
          }
          const float logp = (z[ai] - mx) - std::log(s);
          const float ratio = std::exp(logp - oldlp[i]);
          const float clipped = ratio < lo ? lo : (ratio > hi ? hi : ratio);
          const bool active = ratio == clipped || adv[i] * ratio < adv[i] * clipped;
          const float g = active ? -(adv[i] * ratio) / static_cast<float>(m) : 0.f;
          ratio_g[i] = g;
          for (int k = 0; k < A; ++k) dz[k] = -g * (dz[k] / s);
          dz[ai] += g;
        }
        backward(nets[0], w, m, x, static_cast<int>(A));
        // critic: value loss VF_COEF * mean (V - R)^2 on column 0 of the padded head
        forward(nets[1], w, m, x, 1);
        const float vscale = static_cast<float>(2.0 * a->vf_coef) / static_cast<float>(m);
        for (int i = 0; i < m; ++i) w.dout[i * A] = (w.out[i * A] - ret[i]) * vscale;
        backward(nets[1], w, m, x, 1);
        // per-learner gradient-norm clipping over actor + critic (torch clip_grad_norm_)
        const double sq = sum_squares(grads, 2 * per_net);
        const double coef_d = a->max_grad_norm / (std::sqrt(sq) + 1e-6);
        const float coef = static_cast<float>(coef_d < 1.0 ? coef_d : 1.0);
        // Adam (torch's formula: exp_avg.lerp_(g, 1 - beta1); exp_avg_sq = beta2 v + (1 - beta2) g^2;
        // p -= lr / bc1 * m / (sqrt(v) / sqrt(bc2) + eps))
        step += 1.0;
        const float step_size = static_cast<float>(a->lr / (1.0 - std::pow(a->beta1, step)));
        const float bc2_sqrt = static_cast<float>(std::sqrt(1.0 - std::pow(a->beta2, step)));
        const AdamStep st{coef, 1.f - b1, b2, 1.f - b2, 1.f / bc2_sqrt, eps, step_size};
        for (int n = 0; n < 2; ++n)
          for (int t = 0; t < 6; ++t) adam(st, nets[n].p[t], nets[n].m[t], nets[n].v[t], nets[n].g[t], sz.n[t]);
      }
    }
  }
  std::free(buf);
  std::free(idx);
  std::free(act);
  return 0;
}

// The kernel's tanh on n floats (tests check its accuracy against torch.tanh in float64).
extern "C" void lhf_tanh(const float* x, float* y, int64_t n) {
  int64_t j = 0;
  for (; j + VW <= n; j += VW) vstore(y + j, vtanh(vload(x + j)));
  if (j < n) {
    float tail[VW] = {};
    std::memcpy(tail, x + j, (n - j) * sizeof(float));
    const vf t = vtanh(vload(tail));
    for (int64_t k = 0; k < n - j; ++k) y[j + k] = t[k];
  }
}

// Acting: every learner's actor and critic on its E observations, in blocks of ACT_ROWS rows that
// stay in L1, and one action per row drawn by inverse CDF from the caller's uniforms (the torch
// path's multinomial draws from another stream; same law).  uniforms == null: values only.
extern "C" {

struct ActArgs {  // mirrored by ctypes in native.py
  int64_t L, E, d, A;
  float* params[6];  // as PPOArgs.params
  const float* obs;  // (L, E, d)
  const float* uniforms;  // (L, E) in [0, 1), or null
  int64_t* actions;  // (L, E) out (unused when uniforms is null)
  float* logp;  // (L, E) out (idem)
  float* values;  // (L, E) out
};

int lhf_ppo_act(const ActArgs* a, int64_t l0, int64_t l1) {
  constexpr int ACT_ROWS = 64;
  const int64_t L = a->L, E = a->E, d = a->d, A = a->A;
  if (l0 < 0 || l1 > L || l0 > l1 || d < 1 || A < 1 || E < 1) return 1;
  const int64_t sizes[6] = {d * H, H, H * H, H, H * A, A};
  const int64_t floats = 2 * ACT_ROWS * H + ACT_ROWS * A + A * H + A;
  float* buf = static_cast<float*>(std::aligned_alloc(64, ((floats * 4 + 63) / 64) * 64));
  if (!buf) return 2;
  Work w{static_cast<int>(d), static_cast<int>(A), buf, buf + ACT_ROWS * H, nullptr, nullptr,
         buf + 2 * ACT_ROWS * H, nullptr, nullptr, buf + 2 * ACT_ROWS * H + ACT_ROWS * A};
  float* e = buf + 2 * ACT_ROWS * H + ACT_ROWS * A + A * H;  // one row's exp(z - max z)
  for (int64_t l = l0; l < l1; ++l) {
    Net nets[2];
    for (int n = 0; n < 2; ++n)
      for (int t = 0; t < 6; ++t) nets[n].p[t] = a->params[t] + (n == 0 ? l : L + l) * sizes[t];
    for (int64_t r0 = 0; r0 < E; r0 += ACT_ROWS) {
      const int m = static_cast<int>(r0 + ACT_ROWS <= E ? ACT_ROWS : E - r0);
      const float* x = a->obs + (l * E + r0) * d;
      const int64_t o = l * E + r0;
      forward(nets[1], w, m, x, 1);
      for (int i = 0; i < m; ++i) a->values[o + i] = w.out[i * A];
      if (!a->uniforms) continue;
      forward(nets[0], w, m, x, static_cast<int>(A));
      for (int i = 0; i < m; ++i) {
        const float* z = w.out + i * A;
        float s;
        const float mx = shifted_exp(z, A, e, &s);
        const float target = a->uniforms[o + i] * s;  // inverse CDF on the unnormalised probs
        int64_t act = -1, last = 0;  // last: the last action with a non-zero probability
        float c = 0.f;
        for (int k = 0; k < A; ++k) {
          const float pk = e[k];
          c += pk;
          if (pk > 0.f) last = k;
          if (act < 0 && target < c) act = k;
        }
        if (act < 0) act = last;  // u * s rounded up to s
        a->actions[o + i] = act;
        a->logp[o + i] = (z[act] - mx) - std::log(s);
      }
    }
  }
  std::free(buf);
  return 0;
}

}  // extern "C"
