// The camera of clrender.Camera and kernels/camera.h: ray (a, b, -1) of a pixel centre in
// camera space, its unit world direction; the same float operations in the same order
// (GLSL ES may contract a * b + c and round division differently: docs/explanation/browser.md).
precision highp float;
precision highp int;
precision highp sampler2D;
precision highp isampler2D;
precision highp sampler2DArray;
precision highp sampler3D;
precision highp usampler3D;
precision highp isampler3D;
uniform vec4 intr;            // fx, fy, cx, cy (pixels)
uniform vec3 R0, R1, R2;      // rows of the camera-to-world rotation
uniform vec3 origin;          // camera centre (world)
uniform ivec2 size;           // width, height (pixels)
const int TEX_WIDTH = 2048;   // data textures' row width (clrender/export/limits.py)

ivec2 texel(int i) { return ivec2(i % TEX_WIDTH, i / TEX_WIDTH); }

// (a, b) of the pixel whose centre is `centre` (x + 0.5, image row y + 0.5).
vec2 pixel_ab(vec2 centre) {
  float a = (centre.x - intr.z) / intr.x;
  float b = -((centre.y - intr.w) / intr.y);
  return vec2(a, b);
}

// Unit world direction of pixel q's ray (q.y: image row, 0 at the top).
vec3 ray_dir(ivec2 q) {
  vec2 ab = pixel_ab(vec2(q) + 0.5);
  float x = R0.x * ab.x + R0.y * ab.y - R0.z;
  float y = R1.x * ab.x + R1.y * ab.y - R1.z;
  float z = R2.x * ab.x + R2.y * ab.y - R2.z;
  float norm = sqrt(x * x + y * y + z * z);
  return vec3(x / norm, y / norm, z / norm);
}
