// WebGL2 helpers of the exported page: shaders, data textures, float targets, uniform
// blocks, and the limits the page needs (checked against the browser's own).
export const TEX_WIDTH = 2048;   // row width of data textures (clrender/export/limits.py)

export function context(canvas) {
  const gl = canvas.getContext("webgl2", {antialias: false, depth: false,
                                          preserveDrawingBuffer: true});
  if (!gl) throw new Error("this browser has no WebGL2");
  if (!gl.getExtension("EXT_color_buffer_float"))
    throw new Error("this browser cannot render to float textures (EXT_color_buffer_float)");
  gl.bindVertexArray(gl.createVertexArray());  // draws read no attributes (gl_VertexID)
  return gl;
}

// Throws naming the limit when the browser offers less than `needed`.
export function require(gl, name, needed, what) {
  const have = gl.getParameter(gl[name]);
  if (have < needed) throw new Error(`${what} needs ${name} >= ${needed}; this browser has ${have}`);
}

function compile(gl, type, source, name) {
  const s = gl.createShader(type);
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS))
    throw new Error(`shader ${name}: ${gl.getShaderInfoLog(s)}`);
  return s;
}

// A program from vertex and fragment sources, each prefixed with "#version 300 es" and
// `defines` ({NAME: value}).
export function program(gl, vert, frag, defines, name) {
  const head = "#version 300 es\n" +
    Object.entries(defines).map(([k, v]) => `#define ${k} ${v}\n`).join("");
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, head + vert, name + " (vertex)"));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, head + frag, name + " (fragment)"));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS))
    throw new Error(`program ${name}: ${gl.getProgramInfoLog(p)}`);
  p.loc = (u) => gl.getUniformLocation(p, u);
  return p;
}

// A data texture of an asset {data, shape: [rows, TEX_WIDTH, 4]} (float32 or int32),
// read with texelFetch only.
export function dataTexture(gl, asset) {
  const [rows, width, ch] = asset.shape;
  if (ch !== 4 || width !== TEX_WIDTH) throw new Error("data textures are RGBA, TEX_WIDTH wide");
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  nearest(gl, gl.TEXTURE_2D);
  const isInt = asset.data instanceof Int32Array;
  gl.texImage2D(gl.TEXTURE_2D, 0, isInt ? gl.RGBA32I : gl.RGBA32F, width, rows, 0,
                isInt ? gl.RGBA_INTEGER : gl.RGBA, isInt ? gl.INT : gl.FLOAT, asset.data);
  return t;
}

export function nearest(gl, target) {
  gl.texParameteri(target, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(target, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  gl.texParameteri(target, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(target, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
}

// An RGBA32F 2D array texture of `layers` layers, width x height.
export function floatArray(gl, width, height, layers) {
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D_ARRAY, t);
  nearest(gl, gl.TEXTURE_2D_ARRAY);
  gl.texStorage3D(gl.TEXTURE_2D_ARRAY, 1, gl.RGBA32F, width, height, layers);
  return t;
}

// An RGBA32F 2D texture of width x height and a framebuffer drawing into it: {tex, fb}.
export function floatTarget(gl, width, height) {
  const tex = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, tex);
  nearest(gl, gl.TEXTURE_2D);
  gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, width, height);
  const fb = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
  return { tex, fb };
}

// A framebuffer writing `layers` of array texture `tex` to colour attachments 0.. (and
// `depth`, a renderbuffer, when given).
export function layerTarget(gl, tex, layers, depth) {
  const fb = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  layers.forEach((layer, i) =>
    gl.framebufferTextureLayer(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, tex, 0, layer));
  if (depth) gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
  fb.buffers = layers.map((_, i) => gl.COLOR_ATTACHMENT0 + i);
  const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
  if (status !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`framebuffer incomplete (${status})`);
  return fb;
}

// A uniform buffer holding `data` (Float32Array), bound to binding point `index`.
export function uniformBlock(gl, data, index) {
  const b = gl.createBuffer();
  gl.bindBuffer(gl.UNIFORM_BUFFER, b);
  gl.bufferData(gl.UNIFORM_BUFFER, data, gl.STATIC_DRAW);
  b.index = index;
  b.bytes = data.byteLength;
  return b;
}

export function bindBlock(gl, prog, name, block) {
  const i = gl.getUniformBlockIndex(prog, name);
  if (i === gl.INVALID_INDEX) throw new Error(`no uniform block ${name}`);
  gl.uniformBlockBinding(prog, i, block.index);
  gl.bindBufferBase(gl.UNIFORM_BUFFER, block.index, block);
}

export function bindTexture(gl, prog, name, unit, target, tex) {
  gl.activeTexture(gl.TEXTURE0 + unit);
  gl.bindTexture(target, tex);
  gl.uniform1i(prog.loc(name), unit);
}

// The camera's uniforms (clrender.Camera: fx, fy, cx, cy; R rows; origin), as every
// pass that makes rays reads them.
export function setCamera(gl, prog, cam) {
  const m = cam.c2w;
  gl.uniform4f(prog.loc("intr"), cam.fx, cam.fy, cam.cx, cam.cy);
  gl.uniform3f(prog.loc("R0"), m[0][0], m[0][1], m[0][2]);
  gl.uniform3f(prog.loc("R1"), m[1][0], m[1][1], m[1][2]);
  gl.uniform3f(prog.loc("R2"), m[2][0], m[2][1], m[2][2]);
  gl.uniform3f(prog.loc("origin"), m[0][3], m[1][3], m[2][3]);
  gl.uniform2i(prog.loc("size"), cam.width, cam.height);
}
