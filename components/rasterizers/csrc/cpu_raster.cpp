// CPU kernels of the `cpu` rasterizer backend: tile binning, forward and backward compositing.
//
// Semantics are those of docs/rasterizer.md (gsplat 1.5 "classic"), shared with the torch
// reference: pixel centres at +0.5, alpha = min(0.999, o exp(-sigma)), pairs with sigma < 0 or
// alpha < 1/255 skipped, a pixel stops before the first Gaussian that would bring T to <= 1e-4.
// Projection, SH and the background stay in PyTorch; this file only composites screen-space
// Gaussians. Each tile is one work item (parallel over tiles); inside a tile the Gaussians are
// walked front to back and each tile row is updated LANES pixels at a time, so the inner loops are
// plain branch-free lane loops that the compiler turns into SIMD (AVX-512 / AVX2 / NEON).
//
// Plain C ABI, loaded with ctypes: no Python or torch headers, so it compiles in about a second.
// Layouts (all row-major, float32 unless noted; "rank" = position in a camera's depth order):
//   order [C, N] int64 Gaussian indices front to back; means2d [C*N, 2]; conics [C*N, 3] =
//   (a, b, c) of [[a, b], [b, c]]; opac [C*N]; payload [C*N, nc] (colour channels then camera z);
//   packed [C*N, pack_stride(nc)] per-Gaussian records in rank order (one cache line for RGB);
//   offsets [C*tiles + 1], gids [P] int32 = c*N + rank, each tile's list front to back;
//   out_acc [C, H, W, nc]; out_T [C, H, W] final transmittance; out_last [C, H, W] int32 end of
//   the list part a pixel walked; out_count [C, H, W] int32 optional number of blended Gaussians;
//   v_acc, v_T gradients of out_acc, out_T; grads [C*N, 6 + nc] = (mean x,
//   mean y, conic a, b, c, opacity, payload...) in the original Gaussian order.
// Every entry point takes the number of threads to use (no global state).
//
// Tuning macros (defaults measured best on Zen 4 / AVX-512, docs/rasterizer.md "Speed"):
// TDH_OPENMP (parallel loops through OpenMP instead of std::thread), TDH_AHEAD (prefetch
// distance, 0 = off), TDH_NARROW (8-lane path for narrow splats), TDH_LIBM_EXP (libm/libmvec expf
// instead of the inline polynomial).

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <thread>
#include <vector>

#ifdef TDH_OPENMP
#include <omp.h>
#endif

#include "../../native/csrc/fast_exp.h"

namespace {

constexpr int LANES = 16;  // pixels per vector step (one row of a 16-px tile)
constexpr float ALPHA_MAX = 0.999f;
constexpr float ALPHA_MIN = 1.0f / 255.0f;
constexpr float T_MIN = 1e-4f;
constexpr int NG = 6;           // geometric gradient slots before the payload ones
constexpr int REC = 8;          // packed record: mx, my, a, b, c, o, ex, ey, then the payload
constexpr int MAX_NC = 64;      // payload channels supported
constexpr int LIVE_SCAN = 8;    // forward: recount live pixels after this many Gaussians
#ifndef TDH_AHEAD
#define TDH_AHEAD 4
#endif
constexpr int AHEAD = TDH_AHEAD;  // prefetch distance in list entries (records are scattered in L3)

int pack_stride(int nc) { return (REC + nc + 15) / 16 * 16; }  // whole 64-byte lines
int grad_stride(int nc) { return (NG + nc + 15) / 16 * 16; }

// Zero-filled float buffer aligned to cache lines (std::vector only guarantees 16 bytes).
struct LineBuffer {
    struct Free {
        void operator()(float* p) const { std::free(p); }
    };
    std::unique_ptr<float, Free> mem;
    explicit LineBuffer(size_t n) {
        const size_t bytes = std::max<size_t>(64, (n * sizeof(float) + 63) / 64 * 64);
        mem.reset(static_cast<float*>(std::aligned_alloc(64, bytes)));
        if (!mem) throw std::bad_alloc();
        std::memset(mem.get(), 0, bytes);
    }
    float* data() const { return mem.get(); }
};

// Runs f(item, thread_id) for item in [0, n). By default items are handed out one at a time,
// first come first served (tiles vary a lot). With `fixed`, thread t takes items t, t + nthreads,
// ...: each thread then sums the same items in the same order on every call (reproducible sums).
template <class F>
void parallel_for(int n, int nthreads, F&& f, bool fixed = false) {
    nthreads = std::max(1, std::min(nthreads, n));
    if (nthreads == 1) {
        for (int i = 0; i < n; ++i) f(i, 0);
        return;
    }
#ifdef TDH_OPENMP
    if (fixed) {
#pragma omp parallel for schedule(static, 1) num_threads(nthreads)
        for (int i = 0; i < n; ++i) f(i, omp_get_thread_num());
    } else {
#pragma omp parallel for schedule(dynamic, 1) num_threads(nthreads)
        for (int i = 0; i < n; ++i) f(i, omp_get_thread_num());
    }
#else
    std::atomic<int> next{0};
    auto work = [&](int tid) {
        if (fixed) {
            for (int i = tid; i < n; i += nthreads) f(i, tid);
        } else {
            for (int i = next.fetch_add(1); i < n; i = next.fetch_add(1)) f(i, tid);
        }
    };
    std::vector<std::thread> pool;
    for (int t = 1; t < nthreads; ++t) pool.emplace_back(work, t);
    work(0);
    for (auto& th : pool) th.join();
#endif
}

#ifdef TDH_LIBM_EXP
inline float vexp(float x) { return std::exp(x); }
#else
// exp for x <= 0: the shared inline polynomial (components/native/csrc/fast_exp.h).
inline float vexp(float x) { return tdh::exp_nonpositive(x); }
#endif

// Half extents (ex, ey) of the ellipse where alpha can reach 1/255 (sigma <= log(255 o)):
// sqrt(2 log(255 o) cov_xx), cov = inverse conic. Slightly enlarged: the exact per-pixel alpha
// test decides, the extents only skip work. ey < 0 marks a Gaussian that never reaches 1/255.
inline void reach(float a, float b, float c, float o, float& ex, float& ey) {
    if (!(o >= ALPHA_MIN)) {
        ex = ey = -1.0f;
        return;
    }
    const float lim = std::log(255.0f * o) * 1.0001f + 1e-3f;
    const float det = a * c - b * b;
    if (!(det > 0.0f) || !(a > 0.0f) || !(c > 0.0f)) {
        ex = ey = 1e30f;  // degenerate conic: no cut
        return;
    }
    ex = std::sqrt(2.0f * lim * c / det) + 1e-3f;
    ey = std::sqrt(2.0f * lim * a / det) + 1e-3f;
}

struct TileBox {
    int cam, px0, py0, tw, th, chunks, rw;  // rw = padded row width (chunks * LANES)
};

// Where one Gaussian can reach alpha >= 1/255 inside a tile: rows [r0, r1) and a lane window
// [l0, l0 + NARROW) when its ellipse is narrow enough (then 8-lane vectors do half the work),
// else every chunk of the row (narrow = false). False when the ellipse misses the tile's pixel
// centres altogether (its box may overlap the tile while alpha stays below 1/255).
struct Span {
    int r0, r1, l0;
    bool narrow;
};

#ifndef TDH_NARROW
#define TDH_NARROW 1
#endif
constexpr int NARROW = 8;

inline bool reach_span(const float* rec, const TileBox& B, Span& sp) {
    const float ex = rec[6], ey = rec[7];
    if (ey < 0.0f) return false;
    const float xc = rec[0] - 0.5f - static_cast<float>(B.px0);  // centre in tile pixel-index units
    if (xc + ex < 0.0f || xc - ex > static_cast<float>(B.tw - 1)) return false;
    const float yc = rec[1] - 0.5f - static_cast<float>(B.py0);
    const float lo = std::ceil(yc - ey), hi = std::floor(yc + ey) + 1.0f;
    sp.r0 = static_cast<int>(std::max(lo, 0.0f));
    sp.r1 = static_cast<int>(std::min(hi, static_cast<float>(B.th)));
    const float c0 = std::ceil(xc - ex), c1 = std::floor(xc + ex);  // reachable lanes [c0, c1]
    sp.narrow = TDH_NARROW && B.chunks == 1 && c1 - c0 < static_cast<float>(NARROW);
    sp.l0 = sp.narrow ? static_cast<int>(std::min(std::max(c0, 0.0f), static_cast<float>(LANES - NARROW))) : 0;
    return sp.r0 < sp.r1;
}

struct Geometry {
    int C, N, H, W, ts, tiles_x, tiles_y, nc;
    int tiles_per_cam() const { return tiles_x * tiles_y; }
};

inline TileBox tile_box(const Geometry& g, int tile) {
    TileBox b;
    const int tpc = g.tiles_per_cam();
    b.cam = tile / tpc;
    const int t = tile % tpc;
    b.px0 = (t % g.tiles_x) * g.ts;
    b.py0 = (t / g.tiles_x) * g.ts;
    b.tw = std::min(g.ts, g.W - b.px0);
    b.th = std::min(g.ts, g.H - b.py0);
    b.chunks = (g.ts + LANES - 1) / LANES;
    b.rw = b.chunks * LANES;
    return b;
}

// ---------------------------------------------------------------------------------------------
// forward

struct Gauss {
    float mx, my, ca, cb, cc, op;
};

inline Gauss load_gauss(const float* rec) { return {rec[0], rec[1], rec[2], rec[3], rec[4], rec[5]}; }

// One Gaussian over NL pixels of a row starting at x index xb: skip / stop rule, blending.
// State pointers are already offset to the first pixel; acc channel k lives at acc[k * npix].
template <int NCT, bool COUNT, int NL>
inline void forward_span(const Gauss& g, const float* col, int nc, int npix, float xb, float dy, int i,
                         float* __restrict T, int32_t* __restrict lv, int32_t* __restrict ls,
                         float* __restrict acc, int32_t* __restrict cnt) {
#pragma omp simd
    for (int l = 0; l < NL; ++l) {
        const float dx = g.mx - ((xb + static_cast<float>(l)) + 0.5f);
        const float sigma = 0.5f * (g.ca * dx * dx + g.cc * dy * dy) + g.cb * dx * dy;
        const float al = std::min(ALPHA_MAX, g.op * vexp(-std::max(sigma, 0.0f)));
        const float t = T[l];
        const bool act = (lv[l] != 0) & (sigma >= 0.0f) & (al >= ALPHA_MIN);
        const float nt = t * (1.0f - al);
        const bool stop = act & (nt <= T_MIN);
        const bool add = act & !stop;
        const float w = add ? al * t : 0.0f;
        for (int k = 0; k < (NCT > 0 ? NCT : nc); ++k) acc[k * npix + l] += w * col[k];
        T[l] = add ? nt : t;
        lv[l] = stop ? 0 : lv[l];
        ls[l] = stop ? i : ls[l];
        if constexpr (COUNT) cnt[l] += add ? 1 : 0;
    }
}

template <int NCT, bool COUNT>
void forward_tile(const Geometry& G, int tile, const float* __restrict packed, const int32_t* __restrict offsets,
                  const int32_t* __restrict gids, float* __restrict out_acc, float* __restrict out_T,
                  int32_t* __restrict out_last, int32_t* __restrict out_count) {
    const int nc = NCT > 0 ? NCT : G.nc;
    const int stride = pack_stride(nc);
    const TileBox B = tile_box(G, tile);
    const int beg = offsets[tile], end = offsets[tile + 1];
    const int npix = B.th * B.rw;
    // per-pixel state, structure of arrays: T, live flag, end index, nc accumulators
    std::vector<float> Tv(npix, 1.0f), accv(static_cast<size_t>(nc) * npix, 0.0f);
    std::vector<int32_t> livev(npix), lastv(npix), countv(COUNT ? npix : 0, 0);
    for (int r = 0; r < B.th; ++r)
        for (int l = 0; l < B.rw; ++l) {
            const bool inside = l < B.tw;
            livev[r * B.rw + l] = inside;
            lastv[r * B.rw + l] = inside ? end : beg;
        }
    std::vector<int> row_live(B.th, B.tw);
    float* Tp = Tv.data();
    float* acc = accv.data();
    int32_t* live = livev.data();
    int32_t* last = lastv.data();
    int32_t* count = countv.data();

    int since_scan = 0;
    for (int i = beg; i < end; ++i) {
        if (AHEAD > 0 && i + AHEAD < end) __builtin_prefetch(packed + static_cast<int64_t>(gids[i + AHEAD]) * stride);
        const float* rec = packed + static_cast<int64_t>(gids[i]) * stride;
        Span sp;
        if (!reach_span(rec, B, sp)) continue;
        const Gauss g = load_gauss(rec);
        float col[NCT > 0 ? NCT : MAX_NC];
        for (int k = 0; k < nc; ++k) col[k] = rec[REC + k];
        for (int r = sp.r0; r < sp.r1; ++r) {
            if (row_live[r] == 0) continue;
            const float dy = g.my - (static_cast<float>(B.py0 + r) + 0.5f);
            if (sp.narrow) {
                const int o = r * B.rw + sp.l0;
                forward_span<NCT, COUNT, NARROW>(g, col, nc, npix, static_cast<float>(B.px0 + sp.l0), dy, i,
                                                 Tp + o, live + o, last + o, acc + o, count + o);
                continue;
            }
            for (int ch = 0; ch < B.chunks; ++ch) {
                const int o = r * B.rw + ch * LANES;
                forward_span<NCT, COUNT, LANES>(g, col, nc, npix, static_cast<float>(B.px0 + ch * LANES), dy, i,
                                                Tp + o, live + o, last + o, acc + o, count + o);
            }
        }
        if (++since_scan == LIVE_SCAN) {  // recount now and then: rows and tiles that are done stop early
            since_scan = 0;
            int n_live = 0;
            for (int r = 0; r < B.th; ++r) {
                int cnt = 0;
                for (int l = 0; l < B.rw; ++l) cnt += live[r * B.rw + l];
                row_live[r] = cnt;
                n_live += cnt;
            }
            if (n_live == 0) break;
        }
    }

    const int64_t cam_off = static_cast<int64_t>(B.cam) * G.H * G.W;
    for (int r = 0; r < B.th; ++r)
        for (int l = 0; l < B.tw; ++l) {
            const int64_t p = cam_off + static_cast<int64_t>(B.py0 + r) * G.W + (B.px0 + l);
            const int o = r * B.rw + l;
            out_T[p] = Tp[o];
            out_last[p] = last[o];
            if (COUNT) out_count[p] = count[o];
            for (int k = 0; k < nc; ++k) out_acc[p * nc + k] = acc[k * npix + o];
        }
}

// ---------------------------------------------------------------------------------------------
// backward
//
// Back to front per pixel, from its end index: T_i = T_{i+1} / (1 - a_i) and, with v the
// output gradient of the pixel (payload channels) and S the v-weighted sum of everything behind
// i (started at v_T T_final: T_final carries the factor 1 - a_i too),
//   dL/da_i = T_i (c_i . v) - S / (1 - a_i),   dL/dc_i = a_i T_i v,   S += a_i T_i (c_i . v).
// Per-lane sums of one Gaussian are reduced once per tile, into per-thread gradient buffers.

template <int NCT, int NL>
inline void backward_span(const Gauss& g, const float* col, int nc, int npix, float xb, float dy, int i,
                          float* __restrict T, float* __restrict S, const int32_t* __restrict ls,
                          const float* __restrict V, float (*__restrict acc)[LANES]) {
#pragma omp simd
    for (int l = 0; l < NL; ++l) {
        const float dx = g.mx - ((xb + static_cast<float>(l)) + 0.5f);
        const float sigma = 0.5f * (g.ca * dx * dx + g.cc * dy * dy) + g.cb * dx * dy;
        const float vis = vexp(-std::max(sigma, 0.0f));
        const float raw = g.op * vis;
        const float al = std::min(ALPHA_MAX, raw);
        const bool act = (i < ls[l]) & (sigma >= 0.0f) & (al >= ALPHA_MIN);
        const float ra = 1.0f / (1.0f - al);
        const float t_after = T[l];
        const float ti = t_after * ra;
        float cv = 0.0f;
        for (int k = 0; k < (NCT > 0 ? NCT : nc); ++k) cv += col[k] * V[k * npix + l];
        const float dlda = ti * cv - S[l] * ra;
        const float w = act ? al * ti : 0.0f;
        const bool free_ = act & (raw < ALPHA_MAX);  // the 0.999 clamp has zero gradient
        const float dlds = free_ ? -raw * dlda : 0.0f;
        acc[0][l] += dlds * (g.ca * dx + g.cb * dy);
        acc[1][l] += dlds * (g.cc * dy + g.cb * dx);
        acc[2][l] += dlds * 0.5f * dx * dx;
        acc[3][l] += dlds * dx * dy;
        acc[4][l] += dlds * 0.5f * dy * dy;
        acc[5][l] += free_ ? vis * dlda : 0.0f;
        for (int k = 0; k < (NCT > 0 ? NCT : nc); ++k) acc[NG + k][l] += w * V[k * npix + l];
        S[l] += w * cv;
        T[l] = act ? ti : t_after;
    }
}

template <int NCT>
void backward_tile(const Geometry& G, int tile, const float* __restrict packed, const int32_t* __restrict offsets,
                   const int32_t* __restrict gids, const float* __restrict fin_T,
                   const int32_t* __restrict fin_last, const float* __restrict v_acc,
                   const float* __restrict v_T, float* __restrict grads) {
    const int nc = NCT > 0 ? NCT : G.nc;
    const int stride = pack_stride(nc);
    const int gs = NG + nc;
    const int gstride = grad_stride(nc);
    const TileBox B = tile_box(G, tile);
    const int beg = offsets[tile];
    const int npix = B.th * B.rw;
    std::vector<float> Tv(npix, 1.0f), Sv(npix, 0.0f), Vv(static_cast<size_t>(nc) * npix, 0.0f);
    std::vector<int32_t> lastv(npix, beg);
    std::vector<int> row_max(B.th, beg);
    const int64_t cam_off = static_cast<int64_t>(B.cam) * G.H * G.W;
    for (int r = 0; r < B.th; ++r)
        for (int l = 0; l < B.tw; ++l) {
            const int64_t p = cam_off + static_cast<int64_t>(B.py0 + r) * G.W + (B.px0 + l);
            const int o = r * B.rw + l;
            Tv[o] = fin_T[p];
            Sv[o] = v_T[p] * fin_T[p];
            lastv[o] = fin_last[p];
            for (int k = 0; k < nc; ++k) Vv[k * npix + o] = v_acc[p * nc + k];
            row_max[r] = std::max(row_max[r], fin_last[p]);
        }
    const int imax = *std::max_element(row_max.begin(), row_max.end());
    float* Tp = Tv.data();
    float* Sp = Sv.data();
    const float* V = Vv.data();
    const int32_t* last = lastv.data();

    alignas(64) float acc[NG + (NCT > 0 ? NCT : MAX_NC)][LANES];
    for (int i = imax - 1; i >= beg; --i) {
        if (AHEAD > 0 && i - AHEAD >= beg) {
            const int64_t ahead = gids[i - AHEAD];
            __builtin_prefetch(packed + ahead * stride);
            __builtin_prefetch(grads + ahead * gstride, 1);
        }
        const int64_t gi = gids[i];
        const float* rec = packed + gi * stride;
        Span sp;
        if (!reach_span(rec, B, sp)) continue;
        const Gauss g = load_gauss(rec);
        float col[NCT > 0 ? NCT : MAX_NC];
        for (int k = 0; k < nc; ++k) col[k] = rec[REC + k];
        for (int j = 0; j < gs; ++j)
            for (int l = 0; l < LANES; ++l) acc[j][l] = 0.0f;
        bool any = false;
        for (int r = sp.r0; r < sp.r1; ++r) {
            if (row_max[r] <= i) continue;
            any = true;
            const float dy = g.my - (static_cast<float>(B.py0 + r) + 0.5f);
            if (sp.narrow) {
                const int o = r * B.rw + sp.l0;
                backward_span<NCT, NARROW>(g, col, nc, npix, static_cast<float>(B.px0 + sp.l0), dy, i, Tp + o, Sp + o,
                                           last + o, V + o, acc);
                continue;
            }
            for (int ch = 0; ch < B.chunks; ++ch) {
                const int o = r * B.rw + ch * LANES;
                backward_span<NCT, LANES>(g, col, nc, npix, static_cast<float>(B.px0 + ch * LANES), dy, i, Tp + o,
                                          Sp + o, last + o, V + o, acc);
            }
        }
        if (!any) continue;
        float* out = grads + gi * gstride;
        for (int j = 0; j < gs; ++j) {
            float sum = 0.0f;
            for (int l = 0; l < LANES; ++l) sum += acc[j][l];
            out[j] += sum;
        }
    }
}

template <class F>
void dispatch_nc(int nc, F&& f) {
    // compile-time channel counts for the common cases (RGB + depth, grey + depth)
    if (nc == 4)
        f(std::integral_constant<int, 4>{});
    else if (nc == 2)
        f(std::integral_constant<int, 2>{});
    else
        f(std::integral_constant<int, 0>{});
}

}  // namespace

extern "C" {

int tdh_abi_version() { return 4; }

int tdh_max_channels() { return MAX_NC; }

int tdh_pack_stride(int nc) { return pack_stride(nc); }

// Counting sort of the (tile, Gaussian) pairs: `order` [C, N] lists each camera's Gaussians
// front to back, `rects` [C*N, 4] their tile ranges (x0, x1, y0, y1), empty when culled.
// Writes offsets [C * tiles + 1] and gids [P] = c*N + rank, every tile's list front to back.
void tdh_bin(int C, int N, int tiles_x, int tiles_y, const int64_t* order, const int32_t* rects,
             int32_t* offsets, int32_t* gids) {
    const int tpc = tiles_x * tiles_y;
    const int nt = C * tpc;
    std::fill(offsets, offsets + nt + 1, 0);
    for (int c = 0; c < C; ++c)
        for (int j = 0; j < N; ++j) {
            const int32_t* rc = rects + 4 * (static_cast<int64_t>(c) * N + order[static_cast<int64_t>(c) * N + j]);
            for (int ty = rc[2]; ty < rc[3]; ++ty)
                for (int tx = rc[0]; tx < rc[1]; ++tx) ++offsets[c * tpc + ty * tiles_x + tx + 1];
        }
    for (int t = 0; t < nt; ++t) offsets[t + 1] += offsets[t];
    std::vector<int32_t> cursor(offsets, offsets + nt);
    for (int c = 0; c < C; ++c)
        for (int j = 0; j < N; ++j) {
            const int32_t* rc = rects + 4 * (static_cast<int64_t>(c) * N + order[static_cast<int64_t>(c) * N + j]);
            for (int ty = rc[2]; ty < rc[3]; ++ty)
                for (int tx = rc[0]; tx < rc[1]; ++tx)
                    gids[cursor[c * tpc + ty * tiles_x + tx]++] = static_cast<int32_t>(c * N + j);
        }
}

// One record per Gaussian in rank order, so that a tile walks one cache line per Gaussian.
void tdh_pack(int nthreads, int C, int N, int nc, const int64_t* order, const float* means2d, const float* conics,
              const float* opac, const float* payload, float* packed) {
    const int stride = pack_stride(nc);
    const int64_t total = static_cast<int64_t>(C) * N;
    const int64_t block = 4096;
    parallel_for(static_cast<int>((total + block - 1) / block), nthreads, [&](int b, int) {
        for (int64_t q = b * block; q < std::min(total, (b + 1) * block); ++q) {
            const int64_t g = (q / N) * N + order[q];
            float* rec = packed + q * stride;
            rec[0] = means2d[2 * g], rec[1] = means2d[2 * g + 1];
            rec[2] = conics[3 * g], rec[3] = conics[3 * g + 1], rec[4] = conics[3 * g + 2];
            rec[5] = opac[g];
            reach(rec[2], rec[3], rec[4], rec[5], rec[6], rec[7]);
            for (int k = 0; k < nc; ++k) rec[REC + k] = payload[g * nc + k];
            for (int k = REC + nc; k < stride; ++k) rec[k] = 0.0f;
        }
    });
}

void tdh_forward(int nthreads, int C, int N, int H, int W, int ts, int nc, const float* packed, const int32_t* offsets,
                 const int32_t* gids, float* out_acc, float* out_T, int32_t* out_last, int32_t* out_count) {
    const Geometry G{C, N, H, W, ts, (W + ts - 1) / ts, (H + ts - 1) / ts, nc};
    const int ntiles = C * G.tiles_per_cam();
    if (out_count != nullptr) {  // diagnostics (benchmarks): generic channel path only
        parallel_for(ntiles, nthreads, [&](int tile, int) {
            forward_tile<0, true>(G, tile, packed, offsets, gids, out_acc, out_T, out_last, out_count);
        });
        return;
    }
    dispatch_nc(nc, [&](auto k) {
        constexpr int K = decltype(k)::value;
        parallel_for(ntiles, nthreads, [&](int tile, int) {
            forward_tile<K, false>(G, tile, packed, offsets, gids, out_acc, out_T, out_last, nullptr);
        });
    });
}

void tdh_backward(int nthreads, int C, int N, int H, int W, int ts, int nc, const float* packed, const int32_t* offsets,
                  const int32_t* gids, const float* fin_T, const int32_t* fin_last, const float* v_acc,
                  const float* v_T, const int64_t* order, float* grads, int fixed) {
    const Geometry G{C, N, H, W, ts, (W + ts - 1) / ts, (H + ts - 1) / ts, nc};
    const int ntiles = C * G.tiles_per_cam();
    nthreads = std::max(1, std::min(nthreads, ntiles));
    const int gs = NG + nc, gstride = grad_stride(nc);
    const int64_t total = static_cast<int64_t>(C) * N;
    // per-thread gradient buffers in rank order (a cache line per Gaussian), then summed and
    // scattered to the original order
    std::vector<LineBuffer> part;
    for (int t = 0; t < nthreads; ++t) part.emplace_back(static_cast<size_t>(total) * gstride);
    dispatch_nc(nc, [&](auto k) {
        constexpr int K = decltype(k)::value;
        parallel_for(
            ntiles, nthreads,
            [&](int tile, int tid) {
                backward_tile<K>(G, tile, packed, offsets, gids, fin_T, fin_last, v_acc, v_T, part[tid].data());
            },
            fixed != 0);
    });
    const int64_t block = 4096;
    parallel_for(static_cast<int>((total + block - 1) / block), nthreads, [&](int b, int) {
        for (int64_t q = b * block; q < std::min(total, (b + 1) * block); ++q) {
            float* out = grads + ((q / N) * N + order[q]) * gs;
            for (int j = 0; j < gs; ++j) {
                float sum = 0.0f;
                for (const auto& p : part) sum += p.data()[q * gstride + j];
                out[j] = sum;
            }
        }
    });
}

}  // extern "C"
