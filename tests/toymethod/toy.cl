// The toy method's renderer: one ray per work-item against a sphere of one colour.
// Twin of tests/toymethod/method.py:render_reference (same float32 operations).
#pragma OPENCL FP_CONTRACT OFF

__kernel void toy_render(__global const float *origins, __global const float *dirs,
                         const float cx, const float cy, const float cz, const float radius,
                         const float r, const float g, const float b,
                         const float bg_r, const float bg_g, const float bg_b,
                         const int n, __global float *rgb, __global float *hit) {
    const int i = get_global_id(0);
    if (i >= n) return;
    // |o + t d - c|^2 = radius^2 with |d| = 1: t^2 + 2 (d . oc) t + |oc|^2 - radius^2 = 0.
    const float ox = origins[3 * i] - cx, oy = origins[3 * i + 1] - cy, oz = origins[3 * i + 2] - cz;
    const float half_b = dirs[3 * i] * ox + dirs[3 * i + 1] * oy + dirs[3 * i + 2] * oz;
    const float c = (ox * ox + oy * oy + oz * oz) - radius * radius;
    const float disc = half_b * half_b - c;
    const int h = disc >= 0.0f && (-half_b + sqrt(disc)) > 0.0f;
    rgb[3 * i] = h ? r : bg_r;
    rgb[3 * i + 1] = h ? g : bg_g;
    rgb[3 * i + 2] = h ? b : bg_b;
    hit[i] = h ? 1.0f : 0.0f;
}
