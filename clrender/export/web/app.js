// The exported page: loads model.json and its assets, builds the method's renderer, and
// gives orbit / pan / zoom, a resolution control, the dataset's cameras and ms a frame.
// window.clrender is the hook tests and benchmarks drive (docs/explanation/browser.md).
import * as G from "./gl.js";
import {NDRF} from "./ndrf.js";

const SHADERS = {
  ndrf: ["camera.glsl", "quad.vert", "blit.frag", "ndrf_gbuf.vert", "ndrf_gbuf.frag",
         "ndrf_conv0.frag", "ndrf_conv1.frag"],
  ngprt: ["camera.glsl", "quad.vert", "blit.frag", "ngprt_march.frag"],
};
const TYPES = {float32: Float32Array, int32: Int32Array, uint8: Uint8Array, uint16: Uint16Array};
const $ = (id) => document.getElementById(id);
const hook = window.clrender = {ready: false, error: null};

async function fetchOk(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
  return r;
}

async function loadModel() {
  const model = await (await fetchOk("model.json")).json();
  if (model.format !== "clrender-web" || model.version !== 1)
    throw new Error(`model.json: format ${model.format} version ${model.version}, ` +
                    "this page reads clrender-web version 1");
  if (!SHADERS[model.method]) throw new Error(`model.json: unknown method ${model.method}`);
  const assets = {}, src = {};
  await Promise.all(Object.entries(model.assets).map(async ([name, a]) => {
    const data = new TYPES[a.dtype](await (await fetchOk(a.file)).arrayBuffer());
    if (data.length !== a.shape.reduce((x, y) => x * y, 1))
      throw new Error(`${a.file}: ${data.length} values, model.json says ${a.shape}`);
    assets[name] = {data, shape: a.shape};
  }));
  await Promise.all(SHADERS[model.method].map(async (f) => { src[f] = await (await fetchOk(f)).text(); }));
  return {model, assets, src};
}

async function makeRenderer(gl, model, assets, src) {
  if (model.method === "ndrf") return new NDRF(gl, model, assets, src);
  const {NGPRT} = await import("./ngprt.js");
  return new NGPRT(gl, model, assets, src);
}

// --- camera: c2w as rows (NeRF/Blender convention), intrinsics scaled by the control ----
const v3 = {
  add: (a, b) => a.map((x, i) => x + b[i]), sub: (a, b) => a.map((x, i) => x - b[i]),
  mul: (a, s) => a.map((x) => x * s), dot: (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2],
  cross: (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]],
};
v3.norm = (a) => v3.mul(a, 1 / Math.hypot(...a));
// Rodrigues: v turned by angle t about the unit axis k.
v3.rot = (v, k, t) => v3.add(v3.add(v3.mul(v, Math.cos(t)), v3.mul(v3.cross(k, v), Math.sin(t))),
                             v3.mul(k, v3.dot(k, v) * (1 - Math.cos(t))));
const column = (m, j) => [m[0][j], m[1][j], m[2][j]];

class View {
  constructor(cam) { this.set(cam); }
  set(cam) {
    this.base = cam;
    this.right = column(cam.c2w, 0);
    this.up = column(cam.c2w, 1);
    this.back = column(cam.c2w, 2);
    this.origin = column(cam.c2w, 3);
    this.worldUp = this.up;
    // orbit about the point ahead nearest the world origin (at least 0.3 away)
    const ahead = Math.max(v3.dot(v3.sub([0, 0, 0], this.origin), v3.mul(this.back, -1)), 0.3);
    this.target = v3.sub(this.origin, v3.mul(this.back, ahead));
  }
  orbit(dx, dy) {
    const turn = (axis, t) => {
      this.right = v3.rot(this.right, axis, t); this.up = v3.rot(this.up, axis, t);
      this.back = v3.rot(this.back, axis, t);
      this.origin = v3.add(this.target, v3.rot(v3.sub(this.origin, this.target), axis, t));
    };
    turn(this.worldUp, -dx * 0.005);
    turn(this.right, -dy * 0.005);
  }
  pan(dx, dy) {
    const d = Math.hypot(...v3.sub(this.origin, this.target)) / this.base.fx;
    const move = v3.add(v3.mul(this.right, -dx * d), v3.mul(this.up, dy * d));
    this.origin = v3.add(this.origin, move);
    this.target = v3.add(this.target, move);
  }
  zoom(steps) {
    this.origin = v3.add(this.target, v3.mul(v3.sub(this.origin, this.target), Math.pow(1.1, steps)));
  }
  camera(scale) {
    const b = this.base, w = Math.max(1, Math.round(b.width * scale)),
          h = Math.max(1, Math.round(b.height * scale)), sx = w / b.width, sy = h / b.height;
    const r = [this.right, this.up, this.back, this.origin];
    const c2w = [0, 1, 2].map((i) => r.map((c) => c[i])).concat([[0, 0, 0, 1]]);
    return {fx: b.fx * sx, fy: b.fy * sy, cx: b.cx * sx, cy: b.cy * sy, width: w, height: h, c2w};
  }
}

// --- the page -----------------------------------------------------------------------
function base64(bytes) {
  let s = "";
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

async function main() {
  const canvas = $("view"), gl = G.context(canvas);
  const {model, assets, src} = await loadModel();
  const renderer = await makeRenderer(gl, model, assets, src);
  const blit = G.program(gl, src["quad.vert"], src["camera.glsl"] + src["blit.frag"], {}, "blit");
  const view = new View(model.cameras[0]);
  let times = [];

  // Draws `cam` into the renderer's float frame and onto the canvas; waits for it (a
  // one-pixel read) and returns the milliseconds.
  function draw(cam) {
    const t0 = performance.now();
    renderer.render(cam);
    if (canvas.width !== cam.width || canvas.height !== cam.height) {
      canvas.width = cam.width; canvas.height = cam.height;
    }
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, cam.width, cam.height);
    gl.useProgram(blit);
    G.setCamera(gl, blit, cam);
    G.bindTexture(gl, blit, "frame", 0, gl.TEXTURE_2D, renderer.frame);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
    return performance.now() - t0;
  }

  // Draws the view at the chosen resolution and shows the mean time of the last 30 frames;
  // the first call also marks the load's end.
  function redraw() {
    const cam = view.camera(parseFloat($("scale").value));
    times.push(draw(cam));
    if (hook.loadMs === undefined) hook.loadMs = performance.now();   // since navigation
    if (times.length > 30) times.shift();
    const ms = times.reduce((a, b) => a + b, 0) / times.length;
    $("stats").textContent = `${cam.width}x${cam.height}: ${ms.toFixed(1)} ms a frame ` +
      `(${(1000 / ms).toFixed(1)} fps), load ${(hook.loadMs / 1000).toFixed(2)} s, ` +
      `${(model.bytes / 1e6).toFixed(1)} MB`;
    const size = Math.min(window.innerWidth - 260, window.innerHeight * view.base.width / view.base.height);
    canvas.style.width = `${Math.min(size, view.base.width * 2)}px`;
  }

  let dirty = false;
  function frame() {
    if (dirty || $("continuous").checked) {
      dirty = false;
      redraw();
    }
    requestAnimationFrame(frame);
  }

  model.cameras.forEach((c, i) => $("cameras").add(new Option(c.name, i)));
  $("cameras").onchange = () => { view.set(model.cameras[$("cameras").value]); times = []; dirty = true; };
  $("scale").onchange = () => { times = []; dirty = true; };
  let drag = null;
  canvas.oncontextmenu = (e) => e.preventDefault();
  canvas.onpointerdown = (e) => { drag = {x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2}; };
  window.onpointerup = () => { drag = null; };
  window.onpointermove = (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) view.pan(dx, dy); else view.orbit(dx, dy);
    dirty = true;
  };
  canvas.onwheel = (e) => { e.preventDefault(); view.zoom(Math.sign(e.deltaY)); dirty = true; };

  const scale = new URLSearchParams(location.search).get("scale");   // e.g. ?scale=0.25
  if (scale && [...$("scale").options].some((o) => o.value === scale)) $("scale").value = scale;
  $("title").textContent = `${model.method} (${model.source})`;
  Object.assign(hook, {
    model, cameras: model.cameras, renderer,
    // Draws camera `cam` (clrender.Camera as JSON: fx, fy, cx, cy, width, height, c2w
    // 4x4 rows); returns ms.
    renderView: (cam) => draw(cam),
    // The last frame as base64 float32 RGBA, rows from the image's top.
    readFloat: () => {
      const [w, h] = renderer.size, out = new Float32Array(w * h * 4);
      gl.bindFramebuffer(gl.FRAMEBUFFER, renderer.frameFb);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.FLOAT, out);
      return {width: w, height: h, data: base64(new Uint8Array(out.buffer))};
    },
    setBackground: (rgb) => { renderer.background = rgb; },
  });
  redraw();                           // the first frame, drawn once
  hook.ready = true;
  requestAnimationFrame(frame);
}

main().catch((e) => {
  hook.error = String(e && e.message || e);
  $("error").textContent = hook.error;
  console.error(e);
});
