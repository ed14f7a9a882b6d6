// exp(x) for x <= 0, inline and branch-free so the loops that call it vectorise without libmvec
// (measured faster than libm's expf in the rasterizer, docs/rasterizer.md "Speed"): 2^n * p(r),
// |r| <= ln2/2, a degree-6 polynomial (Cephes expf coefficients), about 1-2 ulp; clamped at -87
// so the result stays a normal float. Shared by the kernels under components/*/csrc.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace tdh {

inline float exp_nonpositive(float x) {
    x = std::max(x, -87.0f);
    const float n = std::floor(x * 1.44269504088896341f + 0.5f);
    float r = x - n * 0.693359375f;
    r = r - n * -2.12194440e-4f;
    float p = 1.9875691500e-4f;
    p = p * r + 1.3981999507e-3f;
    p = p * r + 8.3334519073e-3f;
    p = p * r + 4.1665795894e-2f;
    p = p * r + 1.6666665459e-1f;
    p = p * r + 5.0000001201e-1f;
    p = p * r * r + r + 1.0f;
    const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
    float scale;
    std::memcpy(&scale, &bits, sizeof scale);
    return p * scale;
}

}  // namespace tdh
