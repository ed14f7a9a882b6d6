// The medium's per-pixel read-out (components/medium/pixel_readout.py), forward and backward.
//
// The compositor marches R coarse rays of K intervals and keeps, per interval boundary k, one
// table row of 9 values: Tau_k (optical depth to k), tau_k (of interval k), T_k, S_k (3), L_k (3).
// Each pixel reads its four nearest coarse rays at its own depth zq, rescales the optical depth by
// its own path length (ratio pix_len / ray_len) and blends the four with bilinear weights. In
// PyTorch that is some thirty elementwise ops on [4, H*W] tensors and as many in the backward;
// here it is one pass per pixel. The expressions are those of the torch path
// (MediumCompositor.read), which stays the reference (tests/medium/test_pixel_readout.py).
//
// Plain C ABI, loaded with ctypes. Layouts (row-major): table [R*(K+1), 9]; rays [4, P] int32 ray
// index of each neighbour (int32); wgt [4, P]; pix_len [P]; ray_len [R]; zfar [R] (z each ray was marched
// to); zq [P]; out_tau [P]; out_S [P, 3]; out_L [P, 3] or null (light of the last interval read);
// g_* the gradients of the outputs; grad_table [R*(K+1), 9] is overwritten; grad_zq [P] (or
// null: no gradient into the depth) is overwritten with the gradient of each pixel's depth.
// Every entry point takes the number of threads. The backward scatters into per-thread tables
// summed in thread order, so its result does not depend on scheduling.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <thread>
#include <vector>

#ifdef TDH_OPENMP
#include <omp.h>
#endif

#include "../../native/csrc/fast_exp.h"

namespace {

constexpr int ROW = 9;

// Contiguous chunks of [0, n), one per thread, thread t taking the t-th (a fixed split, so the
// backward's per-thread sums are the same on every call). TDH_OPENMP: torch's own OpenMP pool,
// whose workers are awake after the torch ops around the call; std::threads would compete with
// them spinning (measured: two std::threads were no faster than one).
// Threads actually used for n pixels: at most one per 4096, so small images stay on one.
inline int chunk_threads(int64_t n, int threads) {
    return std::max(1, static_cast<int>(std::min<int64_t>(threads, (n + 4095) / 4096)));
}

template <class F>
void parallel_chunks(int64_t n, int nthreads, F&& f) {
    nthreads = chunk_threads(n, nthreads);
    if (nthreads == 1) {
        f(int64_t(0), n, 0);
        return;
    }
    const int64_t chunk = (n + nthreads - 1) / nthreads;
    auto run = [&](int t) {
        const int64_t a = std::min(n, t * chunk), b = std::min(n, a + chunk);
        f(a, b, t);
    };
#ifdef TDH_OPENMP
#pragma omp parallel for num_threads(nthreads) schedule(static, 1)
    for (int t = 0; t < nthreads; ++t) run(t);
#else
    std::vector<std::thread> pool;
    for (int t = 1; t < nthreads; ++t) pool.emplace_back(run, t);
    run(0);
    for (auto& th : pool) th.join();
#endif
}

// e^-x for x >= 0 and 1 - e^-x, the read-out's only transcendental functions. float: the shared
// inline polynomial (libm's expm1f calls were most of the kernel's time) and 1 - e^-x from its
// Taylor series below x = 1/16, where the difference would cancel (relative error about 1e-7
// either way). double: the library functions (the tests' reference precision).
inline float exp_neg(float x) { return tdh::exp_nonpositive(-x); }
inline float one_minus_exp_neg(float x) {
    const float series = x * (1.0f - x * (0.5f - x * (1.0f / 6.0f - x * (1.0f / 24.0f - x * (1.0f / 120.0f)))));
    return x < 0.0625f ? series : 1.0f - exp_neg(x);
}
inline double exp_neg(double x) { return std::exp(-x); }
inline double one_minus_exp_neg(double x) { return -std::expm1(-x); }

// One neighbour's read at zq: the row it lands in, the interval fraction covered and that
// fraction's derivative in zq (K / zf inside the ray, 0 where the clamp holds it).
template <class T>
struct Read {
    const T* row;
    T f, r, df_dz;
};

template <class T>
inline Read<T> locate(const T* table, int32_t ray, int K, T z, T zf, T pl, T rl) {
    const T zf_safe = std::max(zf, T(1e-12)), u = z / zf_safe;
    const T pos = std::min(std::max(u, T(0)), T(1)) * T(K);
    const int k = std::min(static_cast<int>(std::floor(pos)), K - 1);
    const T df_dz = (u >= T(0) && u <= T(1)) ? T(K) / zf_safe : T(0);
    return {table + (ray * (K + 1) + k) * ROW, pos - T(k), pl / rl, df_dz};  // int32: < 2^31 entries (checked)
}

template <class T>
void forward(int64_t P, int K, int threads, const T* table, const int32_t* rays, const T* wgt,
             const T* pix_len, const T* ray_len, const T* zfar, const T* zq, T* out_tau, T* out_S,
             T* out_L) {
    parallel_chunks(P, threads, [&](int64_t a, int64_t b, int) {
#pragma omp simd
        for (int64_t p = a; p < b; ++p) {
            T acc_t = 0, acc_s[3] = {0, 0, 0}, acc_l[3] = {0, 0, 0};
#pragma GCC unroll 4
            for (int j = 0; j < 4; ++j) {
                const int32_t ray = rays[j * P + p];
                const T w = wgt[j * P + p];
                const Read<T> rd = locate(table, ray, K, zq[p], zfar[ray], pix_len[p], ray_len[ray]);
                const T* row = rd.row;
                const T tau = row[1], e = one_minus_exp_neg(rd.f * tau);
                const T t_ray = row[0] + rd.f * tau, t_pix = t_ray * rd.r;
                const T den = one_minus_exp_neg(t_ray);
                const T frac = den > T(1e-7) ? one_minus_exp_neg(t_pix) / std::max(den, T(1e-7)) : rd.r;
                acc_t += w * t_pix;
                for (int c = 0; c < 3; ++c) {
                    acc_s[c] += w * frac * (row[3 + c] + row[2] * e * row[6 + c]);
                    acc_l[c] += w * row[6 + c];
                }
            }
            out_tau[p] = acc_t;
            for (int c = 0; c < 3; ++c) {
                out_S[p * 3 + c] = acc_s[c];
                if (out_L) out_L[p * 3 + c] = acc_l[c];
            }
        }
    });
}

template <class T>
void backward(int64_t P, int K, int64_t R, int threads, const T* table, const int32_t* rays,
              const T* wgt, const T* pix_len, const T* ray_len, const T* zfar, const T* zq,
              const T* g_tau, const T* g_S, const T* g_L, T* grad_table, T* grad_zq) {
    const int64_t n_tab = R * (K + 1) * ROW;
    const int nt = chunk_threads(P, threads);  // the split parallel_chunks will make
    std::vector<std::vector<T>> local(nt > 1 ? nt : 0);
    std::memset(grad_table, 0, sizeof(T) * n_tab);
    parallel_chunks(P, nt, [&](int64_t a, int64_t b, int t) {
        T* g;
        if (nt > 1) {
            local[t].assign(n_tab, T(0));
            g = local[t].data();
        } else {
            g = grad_table;
        }
        for (int64_t p = a; p < b; ++p) {
            const T gt = g_tau[p];
            const T gs[3] = {g_S[p * 3], g_S[p * 3 + 1], g_S[p * 3 + 2]};
            T g_z = 0;
            for (int j = 0; j < 4; ++j) {
                const int32_t ray = rays[j * P + p];
                const T w = wgt[j * P + p];
                const Read<T> rd = locate(table, ray, K, zq[p], zfar[ray], pix_len[p], ray_len[ray]);
                const T* row = rd.row;
                T* grow = g + (rd.row - table);
                const T f = rd.f, tau = row[1], Tk = row[2];
                const T ef = exp_neg(f * tau), e = one_minus_exp_neg(f * tau);
                const T t_ray = row[0] + f * tau, t_pix = t_ray * rd.r;
                const T den = one_minus_exp_neg(t_ray);
                const bool live = den > T(1e-7);
                const T A = one_minus_exp_neg(t_pix);
                const T frac = live ? A / std::max(den, T(1e-7)) : rd.r;
                T s_ray[3], g_frac = 0;
                for (int c = 0; c < 3; ++c) {
                    s_ray[c] = row[3 + c] + Tk * e * row[6 + c];
                    g_frac += gs[c] * s_ray[c];
                }
                g_frac *= w;
                T g_tpix = w * gt, g_tray = 0;
                if (live) {
                    g_tpix += g_frac * (T(1) - A) / den;
                    g_tray -= g_frac * A * (T(1) - den) / (den * den);
                }
                g_tray += g_tpix * rd.r;
                grow[0] += g_tray;
                T sum_lg = 0;
                for (int c = 0; c < 3; ++c) {
                    const T g_s = w * frac * gs[c];
                    grow[3 + c] += g_s;
                    sum_lg += g_s * row[6 + c];
                    grow[6 + c] += g_s * Tk * e + (g_L ? w * g_L[p * 3 + c] : T(0));
                }
                grow[1] += g_tray * f + Tk * sum_lg * f * ef;
                grow[2] += sum_lg * e;
                g_z += (g_tray * tau + Tk * tau * ef * sum_lg) * rd.df_dz;
            }
            if (grad_zq) grad_zq[p] = g_z;
        }
    });
    for (const std::vector<T>& part : local) {  // in thread order: reproducible sums
        for (int64_t i = 0; i < static_cast<int64_t>(part.size()); ++i) grad_table[i] += part[i];
    }
}

}  // namespace

extern "C" {

int tdh_readout_abi_version() { return 2; }

void tdh_readout_forward_f32(int64_t P, int K, int threads, const float* table, const int32_t* rays,
                             const float* wgt, const float* pix_len, const float* ray_len,
                             const float* zfar, const float* zq, float* out_tau, float* out_S,
                             float* out_L) {
    forward<float>(P, K, threads, table, rays, wgt, pix_len, ray_len, zfar, zq, out_tau, out_S, out_L);
}

void tdh_readout_forward_f64(int64_t P, int K, int threads, const double* table,
                             const int32_t* rays, const double* wgt, const double* pix_len,
                             const double* ray_len, const double* zfar, const double* zq,
                             double* out_tau, double* out_S, double* out_L) {
    forward<double>(P, K, threads, table, rays, wgt, pix_len, ray_len, zfar, zq, out_tau, out_S, out_L);
}

void tdh_readout_backward_f32(int64_t P, int K, int64_t R, int threads, const float* table,
                              const int32_t* rays, const float* wgt, const float* pix_len,
                              const float* ray_len, const float* zfar, const float* zq,
                              const float* g_tau, const float* g_S, const float* g_L,
                              float* grad_table, float* grad_zq) {
    backward<float>(P, K, R, threads, table, rays, wgt, pix_len, ray_len, zfar, zq, g_tau, g_S, g_L,
                    grad_table, grad_zq);
}

void tdh_readout_backward_f64(int64_t P, int K, int64_t R, int threads, const double* table,
                              const int32_t* rays, const double* wgt, const double* pix_len,
                              const double* ray_len, const double* zfar, const double* zq,
                              const double* g_tau, const double* g_S, const double* g_L,
                              double* grad_table, double* grad_zq) {
    backward<double>(P, K, R, threads, table, rays, wgt, pix_len, ray_len, zfar, zq, g_tau, g_S,
                     g_L, grad_table, grad_zq);
}

}  // extern "C"
