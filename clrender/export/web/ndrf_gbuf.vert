// NDRF screen buffer, one mesh: triangle gl_VertexID / 3 to camera space, its edge
// normals, plane normal and offset as kernels/ndrf_raster.cl's setup computes them (flat,
// for the fragment's exact test), and its corner placed on screen, its edges moved DILATE
// pixels outward so that the hardware's coverage contains every pixel
// centre the exact test covers. Image row y goes to framebuffer row y.
uniform isampler2D faces;     // (i0, i1, i2, 0) per face
uniform sampler2D verts;      // (x, y, z, 0) per vertex, world units
flat out ivec4 vid;           // i0, i1, i2, face
flat out vec3 c0, c1, c2, nrm;
flat out float plane;
const float NEAR = 1e-3, FAR = 1e4;

vec3 to_camera(vec3 p) {
  float qx = p.x - origin.x, qy = p.y - origin.y, qz = p.z - origin.z;
  return vec3(R0.x * qx + R1.x * qy + R2.x * qz, R0.y * qx + R1.y * qy + R2.y * qz,
              R0.z * qx + R1.z * qy + R2.z * qz);
}

vec3 cross_scaled(vec3 a, vec3 b, float s) {
  return vec3(s * (a.y * b.z - a.z * b.y), s * (a.z * b.x - a.x * b.z),
              s * (a.x * b.y - a.y * b.x));
}

// s (va x vb), as v_lo x (v_hi - v_lo) from the smaller vertex index (exactly negated
// between the two triangles of an edge).
vec3 edge_normal(vec3 va, vec3 vb, int ia, int ib, float s) {
  bool swap = ia >= ib;
  vec3 lo = swap ? vb : va;
  return cross_scaled(lo, (swap ? va : vb) - lo, swap ? -s : s);
}

vec2 on_screen(vec3 p) {      // pixel coordinates (x right, image row down)
  return vec2(intr.z + intr.x * (p.x / -p.z), intr.w - intr.y * (p.y / -p.z));
}

// The move of corner b (edges a-b, b-c, centre m) that offsets both its edges outward by
// DILATE pixels (the mitre, at most MITRE pixels long: a sliver's sharp corner keeps a
// smaller but positive margin); along the centre's direction for a corner without two
// edges.
const float MITRE = 16.0;
vec2 outward(vec2 a, vec2 b, vec2 m) {
  vec2 e = b - a, n = vec2(e.y, -e.x);
  float len = length(n);
  if (len == 0.0) return vec2(0.0);
  n /= len;
  return dot(n, m - a) > 0.0 ? -n : n;
}

vec2 dilation(vec2 a, vec2 b, vec2 c, vec2 m) {
  vec2 n1 = outward(a, b, m), n2 = outward(b, c, m);
  float k = 1.0 + dot(n1, n2);
  if (n1 == vec2(0.0) || n2 == vec2(0.0) || k < 1e-6) {    // no two edges at b
    vec2 away = b - m;
    float len = length(away);
    return len == 0.0 ? away : away * (DILATE / len);
  }
  vec2 move = DILATE * (n1 + n2) / k;
  float len = length(move);
  return len > MITRE ? move * (MITRE / len) : move;
}

void main() {
  int face = gl_VertexID / 3, corner = gl_VertexID - 3 * (gl_VertexID / 3);
  ivec4 f = texelFetch(faces, texel(face), 0);
  vec3 v[3];
  v[0] = to_camera(texelFetch(verts, texel(f.x), 0).xyz);
  v[1] = to_camera(texelFetch(verts, texel(f.y), 0).xyz);
  v[2] = to_camera(texelFetch(verts, texel(f.z), 0).xyz);
  vec3 n = cross_scaled(v[1] - v[0], v[2] - v[0], 1.0);
  float V = n.x * v[0].x + n.y * v[0].y + n.z * v[0].z;
  float s = V > 0.0 ? 1.0 : -1.0;
  c0 = edge_normal(v[1], v[2], f.y, f.z, s);
  c1 = edge_normal(v[2], v[0], f.z, f.x, s);
  c2 = edge_normal(v[0], v[1], f.x, f.y, s);
  nrm = s * n;
  plane = s * V;
  vid = ivec4(f.xyz, face);
  vec3 p = v[corner];
  float w = -p.z;
  float zc = (w * (FAR + NEAR) - 2.0 * FAR * NEAR) / (FAR - NEAR);
  vec2 wh = vec2(size);
  if (-v[0].z > NEAR && -v[1].z > NEAR && -v[2].z > NEAR) {
    vec2 s0 = on_screen(v[0]), s1 = on_screen(v[1]), s2 = on_screen(v[2]);
    vec2 here = corner == 0 ? s0 : (corner == 1 ? s1 : s2);
    vec2 prev = corner == 0 ? s2 : (corner == 1 ? s0 : s1);
    vec2 next = corner == 0 ? s1 : (corner == 1 ? s2 : s0);
    here += dilation(prev, here, next, (s0 + s1 + s2) / 3.0);
    gl_Position = vec4((2.0 * here / wh - 1.0) * w, zc, w);
  } else {                    // crossing the camera plane: undilated, the hardware clips
    gl_Position = vec4(2.0 * (intr.z * w + intr.x * p.x) / wh.x - w,
                       2.0 * (intr.w * w - intr.y * p.y) / wh.y - w, zc, w);
  }
}
