// NDRF in WebGL2 (docs/ndrf.md, docs/explanation/browser.md): per mesh the screen buffer by
// rasterisation into three float layers (features 0-3, 4-7, hit position), conv0 as
// full-screen passes of NV float targets, conv1 with sigmoid and compositing into a float
// frame.
import * as G from "./gl.js";

const DILATE = "0.5";        // pixels each corner moves out (the exact test decides)

export class NDRF {
  constructor(gl, model, assets, src) {
    const cfg = model.config, K = cfg.thresholds.length, S = cfg.kernel_size;
    this.gl = gl;
    this.model = model;
    this.K = K;
    this.H4 = Math.ceil(cfg.hidden / 4);
    this.NV = model.conv0_targets;
    this.passes = Math.ceil(this.H4 / this.NV);
    G.require(gl, "MAX_DRAW_BUFFERS", Math.max(3, this.NV), "the screen buffer and conv0");
    G.require(gl, "MAX_ARRAY_TEXTURE_LAYERS", Math.max(3 * K, this.H4), "the float targets");
    const c_in = 11 * K + 3 + 6 * cfg.n_freq;
    const defs = {K, S, C_IN: c_in, NV: this.NV, N_FREQ: cfg.n_freq, H4: this.H4, DILATE};
    this.meshes = model.meshes.map((m, k) => ({
      faces: m.faces,
      facesTex: G.dataTexture(gl, assets[`faces_${k}`]),
      vertsTex: G.dataTexture(gl, assets[`vertices_${k}`]),
      featsTex: G.dataTexture(gl, assets[`features_${k}`]),
    }));
    const cam = src["camera.glsl"];
    this.gbuf = G.program(gl, cam + src["ndrf_gbuf.vert"], cam + src["ndrf_gbuf.frag"], defs, "ndrf_gbuf");
    this.conv0 = G.program(gl, src["quad.vert"], cam + src["ndrf_conv0.frag"], defs, "ndrf_conv0");
    this.conv1 = G.program(gl, src["quad.vert"], cam + src["ndrf_conv1.frag"], defs, "ndrf_conv1");
    const w0 = assets.conv0_w.data, per = w0.length / this.passes;
    this.w0 = [];
    for (let p = 0; p < this.passes; ++p)
      this.w0.push(G.uniformBlock(gl, w0.subarray(p * per, (p + 1) * per), 0));
    this.b0 = assets.conv0_b.data;
    this.w1 = G.uniformBlock(gl, assets.conv1_w.data, 1);
    this.size = [0, 0];
  }

  // Targets for a width x height frame (made again when the size changes).
  resize(width, height) {
    const gl = this.gl;
    if (this.size[0] === width && this.size[1] === height) return;
    if (this.frame) this.release();
    this.size = [width, height];
    this.gbufTex = G.floatArray(gl, width, height, 3 * this.K);
    this.hidTex = G.floatArray(gl, width, height, this.H4);
    const depth = this.depth = gl.createRenderbuffer();
    gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
    gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT32F, width, height);
    this.gbufFb = [...Array(this.K).keys()].map(
      (k) => G.layerTarget(gl, this.gbufTex, [3 * k, 3 * k + 1, 3 * k + 2], depth));
    this.hidFb = [];
    for (let p = 0; p < this.passes; ++p) {
      const layers = [];    // the last pass may have fewer: its spare outputs are dropped
      for (let j = 0; j < this.NV && p * this.NV + j < this.H4; ++j) layers.push(p * this.NV + j);
      this.hidFb.push(G.layerTarget(gl, this.hidTex, layers));
    }
    ({ tex: this.frame, fb: this.frameFb } = G.floatTarget(gl, width, height));
  }

  release() {
    const gl = this.gl;
    [this.gbufTex, this.hidTex, this.frame].forEach((t) => gl.deleteTexture(t));
    [...this.gbufFb, ...this.hidFb, this.frameFb].forEach((f) => gl.deleteFramebuffer(f));
    gl.deleteRenderbuffer(this.depth);
  }

  // Draws camera `cam` ({fx, fy, cx, cy, width, height, c2w}) into this.frame.
  render(cam) {
    const gl = this.gl, [W, H] = [cam.width, cam.height];
    this.resize(W, H);
    gl.viewport(0, 0, W, H);
    gl.disable(gl.BLEND);
    // screen buffer, mesh by mesh
    gl.useProgram(this.gbuf);
    G.setCamera(gl, this.gbuf, cam);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LESS);
    this.meshes.forEach((m, k) => {
      gl.bindFramebuffer(gl.FRAMEBUFFER, this.gbufFb[k]);
      gl.drawBuffers(this.gbufFb[k].buffers);
      for (let i = 0; i < 3; ++i) gl.clearBufferfv(gl.COLOR, i, [0, 0, 0, 0]);
      gl.clearBufferfv(gl.DEPTH, 0, [1]);
      G.bindTexture(gl, this.gbuf, "faces", 0, gl.TEXTURE_2D, m.facesTex);
      G.bindTexture(gl, this.gbuf, "verts", 1, gl.TEXTURE_2D, m.vertsTex);
      G.bindTexture(gl, this.gbuf, "feats", 2, gl.TEXTURE_2D, m.featsTex);
      gl.drawArrays(gl.TRIANGLES, 0, 3 * m.faces);
    });
    gl.disable(gl.DEPTH_TEST);
    // conv0, NV hidden layers a pass
    gl.useProgram(this.conv0);
    G.setCamera(gl, this.conv0, cam);
    G.bindTexture(gl, this.conv0, "gbuf", 0, gl.TEXTURE_2D_ARRAY, this.gbufTex);
    for (let p = 0; p < this.passes; ++p) {
      gl.bindFramebuffer(gl.FRAMEBUFFER, this.hidFb[p]);
      gl.drawBuffers(this.hidFb[p].buffers);
      G.bindBlock(gl, this.conv0, "Conv0", this.w0[p]);
      gl.uniform4fv(this.conv0.loc("b0"), this.b0.subarray(p * 4 * this.NV, (p + 1) * 4 * this.NV));
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    }
    // conv1 and compositing
    gl.useProgram(this.conv1);
    G.setCamera(gl, this.conv1, cam);
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.frameFb);
    gl.drawBuffers([gl.COLOR_ATTACHMENT0]);
    G.bindTexture(gl, this.conv1, "hid", 0, gl.TEXTURE_2D_ARRAY, this.hidTex);
    G.bindTexture(gl, this.conv1, "gbuf", 1, gl.TEXTURE_2D_ARRAY, this.gbufTex);
    G.bindBlock(gl, this.conv1, "Conv1", this.w1);
    gl.uniform3fv(this.conv1.loc("b1"), this.model.conv1_b);
    gl.uniform3fv(this.conv1.loc("background"), this.background || this.model.background);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }
}
