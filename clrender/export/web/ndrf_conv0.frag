// NDRF conv0 (docs/ndrf.md), 4 NV of its hidden channels: S x S taps padded bottom/right
// (outside the image: zeros), input channels [8K features | 3K positions | view encoding
// of the tap pixel's ray], then ReLU. Defines: K, S, C_IN, NV, N_FREQ.
uniform sampler2DArray gbuf;            // layers 3k, 3k + 1: features; 3k + 2: position
layout(std140) uniform Conv0 { vec4 w0[S * S * C_IN * NV]; };  // [tap][channel][target]
uniform vec4 b0[NV];
layout(location = 0) out vec4 hidden0;   // NV of these (outputs index by constants only)
#if NV > 1
layout(location = 1) out vec4 hidden1;
#endif
#if NV > 2
layout(location = 2) out vec4 hidden2;
#endif
#if NV > 3
layout(location = 3) out vec4 hidden3;
#endif

vec4 acc[NV];

void add(int channel, float x) {
  for (int j = 0; j < NV; ++j) acc[j] += x * w0[channel * NV + j];
}

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  for (int j = 0; j < NV; ++j) acc[j] = b0[j];
  for (int dy = 0; dy < S; ++dy)
    for (int dx = 0; dx < S; ++dx) {
      ivec2 q = p + ivec2(dx, dy);
      if (q.x >= size.x || q.y >= size.y) continue;
      int base = (dy * S + dx) * C_IN;
      for (int k = 0; k < K; ++k) {
        vec4 lo = texelFetch(gbuf, ivec3(q, 3 * k), 0), hi = texelFetch(gbuf, ivec3(q, 3 * k + 1), 0);
        int c = base + 8 * k;
        add(c, lo.x); add(c + 1, lo.y); add(c + 2, lo.z); add(c + 3, lo.w);
        add(c + 4, hi.x); add(c + 5, hi.y); add(c + 6, hi.z); add(c + 7, hi.w);
        vec3 x = texelFetch(gbuf, ivec3(q, 3 * k + 2), 0).xyz;
        c = base + 8 * K + 3 * k;
        add(c, x.x); add(c + 1, x.y); add(c + 2, x.z);
      }
      vec3 d = ray_dir(q);
      int c = base + 11 * K;
      add(c, d.x); add(c + 1, d.y); add(c + 2, d.z);
      for (int i = 0; i < N_FREQ; ++i) {
        vec3 a = float(1 << i) * d, sa = sin(a), ca = cos(a);
        int ci = c + 3 + 6 * i;
        add(ci, sa.x); add(ci + 1, sa.y); add(ci + 2, sa.z);
        add(ci + 3, ca.x); add(ci + 4, ca.y); add(ci + 5, ca.z);
      }
    }
  hidden0 = max(acc[0], 0.0);
#if NV > 1
  hidden1 = max(acc[1], 0.0);
#endif
#if NV > 2
  hidden2 = max(acc[2], 0.0);
#endif
#if NV > 3
  hidden3 = max(acc[3], 0.0);
#endif
}
