// NGP-RT in WebGL2 (docs/ngprt.md, docs/explanation/browser.md): one full-screen pass marches every
// pixel's ray (ngprt_march.frag) into a float frame.
import * as G from "./gl.js";

// A 3D texture of a (R, R, R) grid asset, x slowest (texel (z, y, x)): uint8 -> R8UI,
// int32 -> R32I.
function grid3d(gl, asset) {
  const [nx, ny, nz] = asset.shape, isInt = asset.data instanceof Int32Array;
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_3D, t);
  G.nearest(gl, gl.TEXTURE_3D);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  gl.texImage3D(gl.TEXTURE_3D, 0, isInt ? gl.R32I : gl.R8UI, nz, ny, nx, 0, gl.RED_INTEGER,
                isInt ? gl.INT : gl.UNSIGNED_BYTE, asset.data);
  return t;
}

export class NGPRT {
  constructor(gl, model, assets, src) {
    this.gl = gl;
    this.model = model;
    const n = model.defines.OCC_RES;
    G.require(gl, "MAX_3D_TEXTURE_SIZE", n, "the occupancy grid");
    G.require(gl, "MAX_TEXTURE_IMAGE_UNITS", 10, "the march");
    this.textures = [];
    const bind = (name, target, tex) => this.textures.push([name, target, tex]);
    for (let lev = 0; lev < 5; ++lev)
      bind(`occ${lev}`, gl.TEXTURE_3D, grid3d(gl, assets[`occupancy_${lev}`]));
    bind("gridG", gl.TEXTURE_3D, grid3d(gl, assets.G));
    bind("blockIndex", gl.TEXTURE_3D, grid3d(gl, assets.coarse_block_index));
    bind("blocks", gl.TEXTURE_2D, G.dataTexture(gl, assets.coarse_blocks));
    bind("fine", gl.TEXTURE_2D, G.dataTexture(gl, assets.fine_tables));
    bind("mlp", gl.TEXTURE_2D, G.dataTexture(gl, assets.mlp));
    this.march = G.program(gl, src["quad.vert"], src["camera.glsl"] + src["ngprt_march.frag"],
                           model.defines, "ngprt_march");
    this.size = [0, 0];
  }

  resize(width, height) {
    const gl = this.gl;
    if (this.size[0] === width && this.size[1] === height) return;
    if (this.frame) { gl.deleteTexture(this.frame); gl.deleteFramebuffer(this.frameFb); }
    this.size = [width, height];
    ({ tex: this.frame, fb: this.frameFb } = G.floatTarget(gl, width, height));
  }

  render(cam) {
    const gl = this.gl, p = this.march;
    this.resize(cam.width, cam.height);
    gl.viewport(0, 0, cam.width, cam.height);
    gl.disable(gl.DEPTH_TEST);
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.frameFb);
    gl.drawBuffers([gl.COLOR_ATTACHMENT0]);
    gl.useProgram(p);
    G.setCamera(gl, p, cam);
    this.textures.forEach(([name, target, tex], i) => G.bindTexture(gl, p, name, i, target, tex));
    gl.uniform1f(p.loc("step_s"), this.model.step);
    gl.uniform1f(p.loc("near"), this.model.near);
    gl.uniform1f(p.loc("far"), this.model.far);
    gl.uniform3fv(p.loc("background"), this.background || this.model.background);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }
}
