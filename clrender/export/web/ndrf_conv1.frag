// NDRF conv1 (docs/ndrf.md): S x S taps padded top/left over the hidden channels (zeros
// outside the image), sigmoid, then compositing: the background where no mesh is hit.
// Defines: K, S, H4 (hidden channels / 4).
uniform sampler2DArray hid;             // H4 layers of 4 hidden channels
uniform sampler2DArray gbuf;            // layer 3k + 2: position, w = 1 where mesh k is hit
layout(std140) uniform Conv1 { vec4 w1[S * S * H4 * 4]; };   // [tap][channel] -> rgb
uniform vec3 b1;
uniform vec3 background;
out vec4 rgb;

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec3 acc = b1;
  for (int dy = 0; dy < S; ++dy)
    for (int dx = 0; dx < S; ++dx) {
      ivec2 q = p + ivec2(dx, dy) - (S - 1);
      if (q.x < 0 || q.y < 0) continue;
      int base = (dy * S + dx) * H4 * 4;
      for (int g = 0; g < H4; ++g) {
        vec4 h = texelFetch(hid, ivec3(q, g), 0);
        int c = base + 4 * g;
        acc += h.x * w1[c].xyz + h.y * w1[c + 1].xyz + h.z * w1[c + 2].xyz + h.w * w1[c + 3].xyz;
      }
    }
  bool covered = false;
  for (int k = 0; k < K; ++k) covered = covered || texelFetch(gbuf, ivec3(p, 3 * k + 2), 0).w > 0.5;
  vec3 s = 1.0 / (1.0 + exp(-acc));
  rgb = vec4(covered ? s : background, 1.0);
}
