// NDRF screen buffer, one mesh: the exact first-hit test of kernels/ndrf_raster.cl's tile
// pass at this pixel (edge functions with its tie rule; not covered: discarded), depth
// along the unit ray for the depth test (nearest; the smaller face on a tie, by draw
// order), then the barycentric blend of the hit's vertex features and positions
// (docs/ndrf.md "The screen buffer", as clrender/ndrf/shader_ref.py computes it).
uniform sampler2D verts;      // (x, y, z, 0) per vertex
uniform sampler2D feats;      // 8 features per vertex: texels 2v, 2v + 1
flat in ivec4 vid;
flat in vec3 c0, c1, c2, nrm;
flat in float plane;
layout(location = 0) out vec4 f_lo;     // features 0-3
layout(location = 1) out vec4 f_hi;     // features 4-7
layout(location = 2) out vec4 pos;      // hit position (world), 1 (hit)

bool owns_ties(vec3 c) {      // c lexicographically positive
  return c.x > 0.0 || (c.x == 0.0 && (c.y > 0.0 || (c.y == 0.0 && c.z > 0.0)));
}

bool inside(float e, vec3 c) { return e > 0.0 || (e == 0.0 && owns_ties(c)); }

void main() {
  vec2 ab = pixel_ab(gl_FragCoord.xy);
  float e0 = c0.x * ab.x + (c0.y * ab.y - c0.z), e1 = c1.x * ab.x + (c1.y * ab.y - c1.z),
        e2 = c2.x * ab.x + (c2.y * ab.y - c2.z), en = nrm.x * ab.x + (nrm.y * ab.y - nrm.z);
  if (!(inside(e0, c0) && inside(e1, c1) && inside(e2, c2) && en > 0.0)) discard;
  float inv_en = 1.0 / en;
  float u = clamp(e1 * inv_en, 0.0, 1.0);
  float v = clamp(e2 * inv_en, 0.0, 1.0 - u);
  float t = plane * inv_en * sqrt(ab.x * ab.x + (ab.y * ab.y + 1.0));
  gl_FragDepth = t / (t + 1.0);         // monotonic in t, in [0, 1)
  float w = 1.0 - u - v;
  f_lo = w * texelFetch(feats, texel(2 * vid.x), 0) + u * texelFetch(feats, texel(2 * vid.y), 0)
         + v * texelFetch(feats, texel(2 * vid.z), 0);
  f_hi = w * texelFetch(feats, texel(2 * vid.x + 1), 0)
         + u * texelFetch(feats, texel(2 * vid.y + 1), 0)
         + v * texelFetch(feats, texel(2 * vid.z + 1), 0);
  pos = vec4(w * texelFetch(verts, texel(vid.x), 0).xyz + u * texelFetch(verts, texel(vid.y), 0).xyz
             + v * texelFetch(verts, texel(vid.z), 0).xyz, 1.0);
}
