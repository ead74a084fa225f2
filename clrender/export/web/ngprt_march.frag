// NGP-RT, one pixel (docs/ngprt.md): the ray's lattice, the march with the occupancy mip
// (and, bounded, the closed-form skip with G), Eq. 6-8 features of every fusion variant,
// compositing, the deferred MLP, the background. The float32 operations of
// clrender/ngprt/render_ref.py in its order; GLSL ES may contract a * b + c and round
// division differently (docs/explanation/browser.md says what that changes).
// Defines (clrender/export/ngprt.py): L_C OCC_RES LEVELS T_SIZE G_RES CB CC CT N_ATT VARIANT
// UNBOUNDED HIDDEN FHIDDEN T_STOP SH_C0..10 VARIANT_* O_* (texel offsets in `mlp`).
uniform highp usampler3D occ0, occ1, occ2, occ3, occ4, gridG;
uniform highp isampler3D blockIndex;
uniform sampler2D blocks;     // coarse corners, CT texels each
uniform sampler2D fine;       // hash entries, 2 texels each
uniform sampler2D mlp;        // weights, 4 outputs a texel
uniform float step_s, near, far;
uniform vec3 background;
out vec4 rgb_out;

const float BIG = 1e30;       // "infinite" exit distance (GLSL ES has no INFINITY)

// ---- space ------------------------------------------------------------------------
vec3 contract(vec3 x) {
  vec3 ax = abs(x);
  float m = max(max(ax.x, ax.y), ax.z);
  if (m <= 1.0) return x;
  vec3 s = x / m;
  vec3 scaled = s * (2.0 - 1.0 / m);
  return vec3(ax.x == m ? scaled.x : s.x, ax.y == m ? scaled.y : s.y, ax.z == m ? scaled.z : s.z);
}

vec3 to_grid(vec3 x) {
#if UNBOUNDED
  return (contract(x) + 2.0) / 4.0;
#else
  return (x + 1.0) / 2.0;
#endif
}

ivec3 cell(vec3 u, int res) {
  return ivec3(clamp(floor(u * float(res)), vec3(0.0), vec3(float(res - 1))));
}

uint occ_at(int lev, vec3 u) {
  ivec3 i = cell(u, OCC_RES >> lev);
  if (lev == 0) return texelFetch(occ0, i.zyx, 0).r;
  if (lev == 1) return texelFetch(occ1, i.zyx, 0).r;
  if (lev == 2) return texelFetch(occ2, i.zyx, 0).r;
  if (lev == 3) return texelFetch(occ3, i.zyx, 0).r;
  return texelFetch(occ4, i.zyx, 0).r;
}

// The first level, coarse (4) to fine (0), empty at u; -1: a sample.
int exit_level(vec3 u) {
  for (int lev = 4; lev >= 0; --lev)
    if (occ_at(lev, u) == 0u) return lev;
  return -1;
}

// ---- the lattice ------------------------------------------------------------------
#if UNBOUNDED
float brk[14], cum[14], pA[13], pB[13], pK[13];

void lattice_table(vec3 o, vec3 d, float t0, float t1) {
  float c[12];
  c[0] = (o.y - o.x) / (d.x - d.y);   c[1] = -(o.x + o.y) / (d.x + d.y);
  c[2] = (o.z - o.x) / (d.x - d.z);   c[3] = -(o.x + o.z) / (d.x + d.z);
  c[4] = (o.z - o.y) / (d.y - d.z);   c[5] = -(o.y + o.z) / (d.y + d.z);
  c[6] = (1.0 - o.x) / d.x;  c[7] = (-1.0 - o.x) / d.x;
  c[8] = (1.0 - o.y) / d.y;  c[9] = (-1.0 - o.y) / d.y;
  c[10] = (1.0 - o.z) / d.z; c[11] = (-1.0 - o.z) / d.z;
  for (int i = 0; i < 12; ++i) if (!(c[i] > t0 && c[i] < t1)) c[i] = t1;
  for (int i = 1; i < 12; ++i) {          // insertion sort
    float x = c[i];
    int j = i - 1;
    while (j >= 0 && c[j] > x) { c[j + 1] = c[j]; --j; }
    c[j + 1] = x;
  }
  brk[0] = t0;
  for (int i = 0; i < 12; ++i) brk[i + 1] = c[i];
  brk[13] = t1;
  cum[0] = 0.0;
  for (int q = 0; q < 13; ++q) {
    float ta = brk[q], tb = brk[q + 1];
    float tm = ta + (tb - ta) * 0.5;
    vec3 xm = vec3(o.x + tm * d.x, o.y + tm * d.y, o.z + tm * d.z), am = abs(xm);
    float mm = max(max(am.x, am.y), am.z);
    int a = am.x == mm ? 0 : (am.y == mm ? 1 : 2);
    float sg = xm[a] > 0.0 ? 1.0 : -1.0;
    vec3 p = vec3(o.x + ta * d.x, o.y + ta * d.y, o.z + ta * d.z);
    float ma = sg * p[a], b = sg * d[a];
    vec3 e = d * ma - p * b;
    float K = sqrt(((e.x * e.x + e.y * e.y) + e.z * e.z) + b * b);
    bool inner = mm <= 1.0;
    pA[q] = inner ? 1.0 : ma * ma;
    pB[q] = inner ? 0.0 : ma * b;
    pK[q] = inner ? 1.0 : K;
    float tau = tb - ta;
    cum[q + 1] = cum[q] + (pK[q] * tau) / (pA[q] + pB[q] * tau);
  }
}

// Eq. 9's step in contracted arc length (marches.paper_g_step_unbounded): floor(4 g /
// G_res / s) lattice steps inside G's empty ball, at least 1, at most to the first point
// of the next piece; 1 from the first point of a piece (it may lie on a jump).
int g_step_unbounded(int k, uint g, float s) {
  float sigma = float(k) * s;
  int n = int(floor(4.0 * float(g) / float(G_RES) / s));
  int j = 0;
  for (int q = 1; q < 13; ++q) j += cum[q] <= sigma ? 1 : 0;
  float end = cum[j + 1];
  int kp = int(ceil(end / s));
  if (float(kp - 1) * s >= end) kp -= 1;
  if (j > 0 && float(k - 1) * s < cum[j]) return k + 1;
  return max(k + 1, min(k + n, kp));
}

float lattice_t(float sigma) {          // S^-1
  int j = 0;
  for (int q = 1; q < 13; ++q) j += cum[q] <= sigma ? 1 : 0;
  float r = sigma - cum[j];
  float den = pK[j] - pB[j] * r;
  return den > 0.0 ? min(brk[j] + (pA[j] * r) / den, brk[j + 1]) : brk[j + 1];
}
#endif

// ---- features (Eq. 6-8) ------------------------------------------------------------
float corner_weight(vec3 w, int c) {
  float wx = ((c >> 2) & 1) == 1 ? w.x : 1.0 - w.x;
  float wy = ((c >> 1) & 1) == 1 ? w.y : 1.0 - w.y;
  float wz = (c & 1) == 1 ? w.z : 1.0 - w.z;
  return wx * wy * wz;
}

vec4 coarse[CT];              // the coarse channels at the sample

void coarse_features(vec3 u) {
  ivec3 i = cell(u, L_C);
  vec3 w = u * float(L_C) - vec3(i);
  ivec3 bi = i / CB;
  int b = texelFetch(blockIndex, bi.zyx, 0).r;
  ivec3 r = i - bi * CB;
  for (int q = 0; q < CT; ++q) coarse[q] = vec4(0.0);
  if (b < 0) return;
  for (int c = 0; c < 8; ++c) {
    ivec3 j = r + ivec3((c >> 2) & 1, (c >> 1) & 1, c & 1);
    float wc = corner_weight(w, c);
    int base = (((b * (CB + 1) + j.x) * (CB + 1) + j.y) * (CB + 1) + j.z) * CT;
    for (int q = 0; q < CT; ++q) coarse[q] = coarse[q] + wc * texelFetch(blocks, texel(base + q), 0);
  }
}

float coarse_channel(int c) { return coarse[c / 4][c % 4]; }

void fine_features(vec3 u, int l, out vec4 lo, out vec4 hi) {
  vec3 p = u * float(L_C << (l + 1));
  vec3 fl = floor(p);
  ivec3 i = ivec3(fl);
  vec3 w = p - fl;
  lo = vec4(0.0);
  hi = vec4(0.0);
  for (int c = 0; c < 8; ++c) {
    uvec3 j = uvec3(i + ivec3((c >> 2) & 1, (c >> 1) & 1, c & 1));
    uint h = (j.x * 1u) ^ (j.y * 2654435761u) ^ (j.z * 805459861u);
    int e = 2 * (l * T_SIZE + int(h & uint(T_SIZE - 1)));
    float wc = corner_weight(w, c);
    lo = lo + wc * texelFetch(fine, texel(e), 0);
    hi = hi + wc * texelFetch(fine, texel(e + 1), 0);
  }
}

float sigmoid(float x) { return 1.0 / (1.0 + exp(-x)); }

vec4 weight4(int offset, int row, int group) {    // 4 outputs of a matrix row
  return texelFetch(mlp, texel(offset + row + group), 0);
}

float logit(int i) {          // attention logit i of the -v / -inv variants
#if VARIANT == VARIANT_SHARED_INV || VARIANT == VARIANT_SEPARATE_INV
  return texelFetch(mlp, texel(O_INV + i / 4), 0)[i % 4];
#else
  return coarse_channel(8 + i);
#endif
}

// The fusion of the fine levels into (lo, hi) = 8 channels.
void fuse(vec3 u, out vec4 out_lo, out vec4 out_hi) {
  out_lo = vec4(0.0);
  out_hi = vec4(0.0);
#if VARIANT == VARIANT_MLP
  vec4 x[2 * LEVELS];
  for (int l = 0; l < LEVELS; ++l) fine_features(u, l, x[2 * l], x[2 * l + 1]);
  vec4 h[FHIDDEN / 4];
  for (int g = 0; g < FHIDDEN / 4; ++g) h[g] = weight4(O_FB0, 0, g);
  for (int i = 0; i < 8 * LEVELS; ++i) {
    float xi = x[i / 4][i % 4];
    for (int g = 0; g < FHIDDEN / 4; ++g) h[g] += xi * weight4(O_FW0, i * (FHIDDEN / 4), g);
  }
  out_lo = weight4(O_FB1, 0, 0);
  out_hi = weight4(O_FB1, 0, 1);
  for (int i = 0; i < FHIDDEN; ++i) {
    float hi_ = max(h[i / 4][i % 4], 0.0);
    out_lo += hi_ * weight4(O_FW1, 2 * i, 0);
    out_hi += hi_ * weight4(O_FW1, 2 * i, 1);
  }
#else
  for (int l = 0; l < LEVELS; ++l) {
    vec4 lo, hi;
    fine_features(u, l, lo, hi);
#if VARIANT == VARIANT_SUM
    out_lo = out_lo + lo;
    out_hi = out_hi + hi;
#elif VARIANT == VARIANT_SHARED_INV || VARIANT == VARIANT_SHARED_V
    float a = sigmoid(logit(l));
    out_lo = out_lo + a * lo;
    out_hi = out_hi + a * hi;
#else
    float omega = sigmoid(logit(2 * l)), beta = sigmoid(logit(2 * l + 1));
    out_lo = out_lo + vec4(omega, beta, beta, beta) * lo;
    out_hi = out_hi + beta * hi;
#endif
  }
#endif
}

// ---- the deferred MLP ---------------------------------------------------------------
float sh[16];

void sh4(vec3 d) {
  float x = d.x, y = d.y, z = d.z, xy = x * y, xz = x * z, yz = y * z, x2 = x * x,
        y2 = y * y, z2 = z * z;
  sh[0] = SH_C0;                 sh[1] = -SH_C1 * y;          sh[2] = SH_C1 * z;
  sh[3] = -SH_C1 * x;            sh[4] = SH_C2 * xy;          sh[5] = -SH_C2 * yz;
  sh[6] = SH_C3 * z2 - SH_C4;    sh[7] = -SH_C2 * xz;         sh[8] = SH_C5 * x2 - SH_C5 * y2;
  sh[9] = SH_C6 * y * (-3.0 * x2 + y2);                       sh[10] = SH_C7 * xy * z;
  sh[11] = SH_C8 * y * (1.0 - 5.0 * z2);                      sh[12] = SH_C9 * z * (5.0 * z2 - 3.0);
  sh[13] = SH_C8 * x * (1.0 - 5.0 * z2);                      sh[14] = SH_C10 * z * (x2 - y2);
  sh[15] = SH_C6 * x * (-x2 + 3.0 * y2);
}

vec3 deferred(vec3 diffuse, vec4 specular, vec3 d) {
  sh4(d);
  float x[23];
  x[0] = diffuse.x; x[1] = diffuse.y; x[2] = diffuse.z;
  for (int i = 0; i < 4; ++i) x[3 + i] = specular[i];
  for (int i = 0; i < 16; ++i) x[7 + i] = sh[i];
  const int G = HIDDEN / 4;
  vec4 h1[G], h2[G];
  for (int g = 0; g < G; ++g) h1[g] = weight4(O_B0, 0, g);
  for (int i = 0; i < 23; ++i)
    for (int g = 0; g < G; ++g) h1[g] += x[i] * weight4(O_W0, i * G, g);
  for (int g = 0; g < G; ++g) { h1[g] = max(h1[g], 0.0); h2[g] = weight4(O_B1, 0, g); }
  for (int i = 0; i < HIDDEN; ++i) {
    float hi = h1[i / 4][i % 4];
    for (int g = 0; g < G; ++g) h2[g] += hi * weight4(O_W1, i * G, g);
  }
  vec3 o = vec3(0.0);
  for (int i = 0; i < HIDDEN; ++i) o += max(h2[i / 4][i % 4], 0.0) * weight4(O_W2, i, 0).xyz;
  vec3 z = diffuse + o + weight4(O_B2, 0, 0).xyz;
  return vec3(sigmoid(z.x), sigmoid(z.y), sigmoid(z.z));
}

// ---- the march ----------------------------------------------------------------------
#if !UNBOUNDED
bool in_cell(vec3 o, vec3 d, int k, float s, int res, ivec3 c) {
  float t = float(k) * s;
  return cell(to_grid(vec3(o.x + t * d.x, o.y + t * d.y, o.z + t * d.z)), res) == c;
}

// Next lattice index after an empty point (docs/ngprt.md "skip", bounded): the mip cell's
// exit, checked (bisection to the first point outside), and G's ball; the larger.
int skip_bounded(int k, float t, vec3 o, vec3 d, vec3 u, int lev, float s, float g_end) {
  int res = OCC_RES >> lev;
  float h = 2.0 / float(res);
  ivec3 c = cell(u, res);
  vec3 lo = vec3(c) * h - 1.0, hi = lo + h;
  float t_exit = BIG;
  for (int a = 0; a < 3; ++a)
    if (d[a] != 0.0) t_exit = min(t_exit, ((d[a] > 0.0 ? hi[a] : lo[a]) - o[a]) / d[a]);
  float lim = g_end / s + 2.0;
  int kn = max(k + 1, int(ceil(min(t_exit / s - 1e-3, lim))));
  if (kn - 1 > k && !in_cell(o, d, kn - 1, s, res, c)) {
    int a = k, b = kn - 1;
    while (b - a > 1) {
      int mid = a + (b - a) / 2;
      if (in_cell(o, d, mid, s, res, c)) a = mid; else b = mid;
    }
    kn = b;
  }
  if (res < G_RES) {
    ivec3 gi = cell(u, G_RES);
    uint g = texelFetch(gridG, gi.zyx, 0).r;
    if (g > 0u) {
      float r = 2.0 * float(g) / float(G_RES);
      kn = max(kn, int(floor(min((t + r) / s, lim))));
    }
  }
  return kn;
}
#endif

void main() {
  ivec2 px = ivec2(gl_FragCoord.xy);
  vec3 o = origin, d = ray_dir(px);
  float s = step_s;
#if UNBOUNDED
  float t_start = near, t_end = far;
  lattice_table(o, d, t_start, t_end);
  float g_end = cum[13];
  int k = 0;
#else
  vec3 inv = 1.0 / d, t0 = (-1.0 - o) * inv, t1 = (1.0 - o) * inv;
  vec3 lo = min(t0, t1), hi = max(t0, t1);
  float t_start = max(near, max(max(lo.x, lo.y), lo.z)), t_end = min(min(hi.x, hi.y), hi.z);
  float g_end = t_end;
  int k = t_start <= t_end ? int(ceil(t_start / s)) : 0;
#endif
  float T = 1.0, opacity = 0.0;
  vec3 diffuse = vec3(0.0);
  vec4 specular = vec4(0.0);
  if (t_start <= t_end) {
    while (float(k) * s < g_end && T >= T_STOP) {
      float g = float(k) * s;
#if UNBOUNDED
      float t = lattice_t(g);
#else
      float t = g;
#endif
      vec3 u = to_grid(vec3(o.x + t * d.x, o.y + t * d.y, o.z + t * d.z));
      int lev = exit_level(u);
      if (lev < 0) {
        coarse_features(u);
        vec4 flo, fhi;
        fuse(u, flo, fhi);
        flo = coarse[0] + flo;
        fhi = coarse[1] + fhi;
        float g1 = float(k + 1) * s;
#if UNBOUNDED
        float t1_ = g1 < g_end ? lattice_t(min(g1, g_end)) : far;
#else
        float t1_ = g1;
#endif
        float sigma = exp(flo.x);
        float alpha = 1.0 - exp(-sigma * (t1_ - t));
        float w = T * alpha;
        diffuse = diffuse + w * flo.yzw;
        specular = specular + w * fhi;
        opacity = opacity + w;
        T = T * (1.0 - alpha);
        k += 1;
      } else {
#if UNBOUNDED
        // G's step where G is read and > 0 (the paper's march), else the walk to the next
        // point: the same samples as the kernels' closed-form jumps, more points visited
        uint g = 0u;
        if ((OCC_RES >> lev) < G_RES) g = texelFetch(gridG, cell(u, G_RES).zyx, 0).r;
        k = g > 0u ? g_step_unbounded(k, g, s) : k + 1;
#else
        k = skip_bounded(k, t, o, d, u, lev, s, g_end);
#endif
      }
    }
  }
  vec3 rgb = deferred(diffuse, specular, d);
  rgb_out = vec4(rgb * opacity + background * (1.0 - opacity), 1.0);
}
