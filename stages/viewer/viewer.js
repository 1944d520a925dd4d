// usdbake stream viewer: reads GET /stream (stages/serve.py) and draws the scene as it arrives, under an orbit
// camera (camera.js). With a daylight stream (daylight.js) it draws
// the baked faces relit for the date, hour, place and sky of the controls (controls.js) instead of the grid's light.
//
// Written here, no third-party code: the frame parser, the two stream decoders (formats/mesh_stream.py and
// formats/streaming.py, little-endian), the level-of-detail mapping of Pacanowski et al. 2008 section 4.2,
// the grid reconstruction of section 3.2 (I_n = sum_a n_a^2 I_a, E = max(0, I_n . n)) and a WebGL2 drawing.
// Grid vertices not received yet are left out of the trilinear weights (the Python client fills them by
// push-pull instead); with the whole stream both read the same vectors.
//
// ?limit=F stops reading after that share of the stream bytes (the browser test's checkpoints); ?chunk=N asks
// the server for N-byte frames. window.usdbake exposes the controls and the relit values to tests.
"use strict";

const FRAME_BYTES = 16;

function varints(bytes, count) {
  const out = new Float64Array(count);
  let value = 0, shift = 0, k = 0;
  for (let i = 0; i < bytes.length && k < count; i++) {
    value += (bytes[i] & 0x7f) * Math.pow(2, shift);
    if (bytes[i] & 0x80) { shift += 7; } else { out[k++] = value; value = 0; shift = 0; }
  }
  return out;
}

function decodeMesh(buffer) {
  const view = new DataView(buffer.buffer, buffer.byteOffset, buffer.byteLength);
  if (buffer.byteLength < 24) return null;
  const vertices = view.getUint32(8, true), packets = view.getUint32(16, true), tableBytes = view.getUint32(20, true);
  if (buffer.byteLength < 24 + tableBytes) return null;
  const distance = varints(buffer.subarray(24, 24 + tableBytes), vertices);
  const table = new Int32Array(vertices);
  for (let r = 0; r < vertices; r++) table[r] = distance[r] > 0 ? r - distance[r] : -1;
  const positions = [], corners = [];
  let offset = 24 + tableBytes;
  for (let p = 0; p < packets && offset + 12 <= buffer.byteLength; p++) {
    const count = view.getUint32(offset + 4, true), faces = view.getUint32(offset + 8, true);
    const end = offset + 12 + 12 * count + 12 * faces;
    if (end > buffer.byteLength) break;
    for (let i = 0; i < 3 * count; i++) positions.push(view.getFloat32(offset + 12 + 4 * i, true));
    for (let i = 0; i < 3 * faces; i++) corners.push(view.getUint32(offset + 12 + 12 * count + 4 * i, true));
    offset = end;
  }
  const level = positions.length / 3;
  for (let i = 0; i < corners.length; i++) {  // each corner up its collapse chain to a received vertex
    let c = corners[i];
    while (c >= level) c = table[c];
    corners[i] = c;
  }
  return {positions: new Float32Array(positions), faces: new Uint32Array(corners), level};
}

function rgb9e5(packed) {
  const scale = Math.pow(2, (packed >>> 27) - 15 - 9);
  return [(packed & 0x1ff) * scale, ((packed >>> 9) & 0x1ff) * scale, ((packed >>> 18) & 0x1ff) * scale];
}

function decodeGrid(buffer) {
  if (buffer.byteLength < 52) return null;
  const view = new DataView(buffer.buffer, buffer.byteOffset, buffer.byteLength);
  const res = [view.getInt32(12, true), view.getInt32(16, true), view.getInt32(20, true)];
  const origin = [0, 1, 2].map(a => view.getFloat32(24 + 4 * a, true));
  const cell = [0, 1, 2].map(a => view.getFloat32(36 + 4 * a, true));
  const count = res[0] * res[1] * res[2];
  const vectors = new Float32Array(count * 6 * 9);  // per vertex, hemisphere: rows R, G, B of a vector
  const received = new Uint8Array(count);
  const record = 4 + 18 + 24;
  for (let offset = 52; offset + record <= buffer.byteLength; offset += record) {
    const v = view.getUint32(offset, true);
    received[v] = 1;
    for (let h = 0; h < 6; h++) {
      const q = [0, 1, 2].map(a => view.getUint8(offset + 4 + 3 * h + a) - 128);
      const length = Math.hypot(q[0], q[1], q[2]) || 1;
      const c = rgb9e5(view.getUint32(offset + 22 + 4 * h, true));
      for (let ch = 0; ch < 3; ch++)
        for (let a = 0; a < 3; a++) vectors[(v * 6 + h) * 9 + ch * 3 + a] = c[ch] * q[a] / length;
    }
  }
  return {res, origin, cell, vectors, received};
}

function irradiance(grid, p, n) {
  // Paper 3.2 at p moved half a cell along n (the baker's normal_offset), received corners only.
  const step = 0.5 * Math.min(grid.cell[0], grid.cell[1], grid.cell[2]);
  const g = [0, 1, 2].map(a => Math.min(Math.max((p[a] + n[a] * step - grid.origin[a]) / grid.cell[a], 0), grid.res[a] - 1));
  const i0 = g.map((x, a) => Math.min(Math.floor(x), Math.max(grid.res[a] - 2, 0)));
  const t = g.map((x, a) => grid.res[a] > 1 ? x - i0[a] : 0);
  const out = [0, 0, 0];
  let total = 0;
  const interp = [new Float32Array(9), new Float32Array(9), new Float32Array(9)];
  for (let corner = 0; corner < 8; corner++) {
    const c = [0, 1, 2].map(a => Math.min(i0[a] + ((corner >> a) & 1), grid.res[a] - 1));
    const w = [0, 1, 2].reduce((m, a) => m * (((corner >> a) & 1) ? t[a] : 1 - t[a]), 1);
    const v = c[0] + grid.res[0] * (c[1] + grid.res[1] * c[2]);
    if (!grid.received[v] || w === 0) continue;
    total += w;
    for (let axis = 0; axis < 3; axis++) {
      const h = 2 * axis + (n[axis] < 0 ? 1 : 0);
      for (let k = 0; k < 9; k++) interp[axis][k] += w * grid.vectors[(v * 6 + h) * 9 + k];
    }
  }
  if (total === 0) return out;
  for (let axis = 0; axis < 3; axis++)
    for (let ch = 0; ch < 3; ch++) {
      const row = interp[axis].subarray(3 * ch, 3 * ch + 3);
      out[ch] += n[axis] * n[axis] * (row[0] * n[0] + row[1] * n[1] + row[2] * n[2]) / total;
    }
  return out.map(x => Math.max(x, 0));
}

function vertexNormals(mesh) {
  const n = new Float32Array(mesh.positions.length), P = mesh.positions, F = mesh.faces;
  for (let f = 0; f < F.length; f += 3) {
    const a = 3 * F[f], b = 3 * F[f + 1], c = 3 * F[f + 2];
    const u = [P[b] - P[a], P[b + 1] - P[a + 1], P[b + 2] - P[a + 2]];
    const v = [P[c] - P[a], P[c + 1] - P[a + 1], P[c + 2] - P[a + 2]];
    const cross = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    for (const i of [a, b, c]) for (let k = 0; k < 3; k++) n[i + k] += cross[k];
  }
  for (let i = 0; i < n.length; i += 3) {
    const l = Math.hypot(n[i], n[i + 1], n[i + 2]) || 1;
    n[i] /= l; n[i + 1] /= l; n[i + 2] /= l;
  }
  return n;
}

function shade(meshes, grid) {
  // Per mesh: vertex irradiance (W/m^2) from the grid, or a neutral grey before any light arrives.
  return meshes.map(mesh => {
    if (!mesh) return null;
    const normals = vertexNormals(mesh);
    const colors = new Float32Array(mesh.positions.length).fill(grid ? 0 : 1);
    if (grid) for (let i = 0; i < mesh.level; i++) {
      const e = irradiance(grid, mesh.positions.subarray(3 * i, 3 * i + 3), normals.subarray(3 * i, 3 * i + 3));
      colors.set(e, 3 * i);
    }
    return colors;
  });
}

// ---------------------------------------------------------------------------------------------------------
// Drawing: the streamed meshes with per-vertex grid irradiance, or the daylight faces

const FRAME_BUDGET_MS = 12;  // a coarse preview relights the stream prefix that fits this, from the last whole relight
const SETTLE_MS = 250;  // the whole relight follows once the controls rest this long

const DRAW_VERTEX = `#version 300 es
  in vec3 p; in vec3 e; uniform mat4 viewProjection; out vec3 colour;
  void main() { gl_Position = viewProjection * vec4(p, 1.0); colour = e; }`;
const DRAW_FRAGMENT = `#version 300 es
  precision highp float; in vec3 colour; uniform float exposure; out vec4 outColour;
  void main() { vec3 x = colour * exposure; outColour = vec4(x / (1.0 + x), 1.0); }`;

// Daylight faces: irradiance from the relight target (face index per vertex), radiance = albedo / pi x E,
// tone-mapped, or illuminance (179 lm/W) in false colour on a log scale between two lux levels.
const DAYLIGHT_VERTEX = `#version 300 es
  in vec3 p; in float face; in vec3 albedo;
  uniform mat4 viewProjection; uniform highp sampler2D irradiance; uniform highp isampler2D display;
  uniform highp sampler2D overlay;
  flat out vec4 light; flat out vec3 reflectance; flat out float metric;
  void main() {
    int own = int(face + 0.5);
    int f = texelFetch(display, ivec2(own % 1024, own / 1024), 0).r;  // itself, or its ancestor in a coarse preview
    light = f < 0 ? vec4(0.0) : texelFetch(irradiance, ivec2(f % 256, f / 256), 0);
    metric = texelFetch(overlay, ivec2(own % 1024, own / 1024), 0).r;
    reflectance = albedo;
    gl_Position = viewProjection * vec4(p, 1.0);
  }`;
const DAYLIGHT_FRAGMENT = `#version 300 es
  precision highp float;
  flat in vec4 light; flat in vec3 reflectance; flat in float metric;
  uniform float exposure; uniform int falseColour; uniform vec2 luxRange; uniform vec2 metricRange;
  out vec4 outColour;
  vec3 ramp(float t) {  // blue - cyan - green - yellow - red
    t = clamp(t, 0.0, 1.0);
    return clamp(vec3(1.5 - abs(4.0 * t - 3.0), 1.5 - abs(4.0 * t - 2.0), 1.5 - abs(4.0 * t - 1.0)), 0.0, 1.0);
  }
  void main() {
    if (falseColour == 2) {  // an annual metric, linear between metricRange
      outColour = vec4(ramp((metric - metricRange.x) / (metricRange.y - metricRange.x)), 1.0);
      return;
    }
    if (light.a == 0.0) { outColour = vec4(0.35, 0.35, 0.38, 1.0); return; }  // no coefficients yet
    if (falseColour == 1) {
      float lux = 179.0 * dot(light.rgb, vec3(0.2126, 0.7152, 0.0722));
      outColour = vec4(ramp(log(max(lux, 1e-6) / luxRange.x) / log(luxRange.y / luxRange.x)), 1.0);
      return;
    }
    vec3 x = reflectance / 3.14159265 * light.rgb * exposure;
    outColour = vec4(x / (1.0 + x), 1.0);
  }`;

class Drawing {
  constructor(canvas) {
    this.canvas = canvas;
    this.gl = canvas.getContext("webgl2", {preserveDrawingBuffer: true});
    this.items = [];  // {program, buffers: [[name, data, size]], index, count, uniforms}
  }

  buffer(program, name, data, size) {
    const gl = this.gl, buffer = gl.createBuffer(), location = gl.getAttribLocation(program, name);
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    return {buffer, location, size};
  }

  draw(camera, setUniforms) {
    const gl = this.gl;
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.clearColor(0.08, 0.08, 0.1, 1);
    gl.enable(gl.DEPTH_TEST);
    gl.enable(gl.CULL_FACE);  // one-sided, as the baker's surfaces: a room's near walls open onto its inside
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    const matrix = camera.matrix(this.canvas.width / this.canvas.height);
    for (const item of this.items) {
      gl.useProgram(item.program);
      gl.uniformMatrix4fv(gl.getUniformLocation(item.program, "viewProjection"), false, matrix);
      setUniforms(item);
      for (const b of item.buffers) {
        gl.bindBuffer(gl.ARRAY_BUFFER, b.buffer);
        gl.enableVertexAttribArray(b.location);
        gl.vertexAttribPointer(b.location, b.size, b.type || gl.FLOAT, !!b.normalized, 0, 0);
      }
      if (item.index) {
        gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, item.index);
        gl.drawElements(gl.TRIANGLES, item.count, gl.UNSIGNED_INT, 0);
      } else {
        gl.drawArrays(gl.TRIANGLES, 0, item.count);
      }
      for (const b of item.buffers) gl.disableVertexAttribArray(b.location);
    }
  }
}

function meshItems(drawing, meshes, colors) {
  const gl = drawing.gl, program = compile(gl, DRAW_VERTEX, DRAW_FRAGMENT);
  let peak = 1e-12;
  for (const c of colors) if (c) for (const x of c) peak = Math.max(peak, x);
  return meshes.map((mesh, k) => {
    if (!mesh || !mesh.faces.length) return null;
    const index = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, index);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, mesh.faces, gl.STATIC_DRAW);
    return {program, buffers: [drawing.buffer(program, "p", mesh.positions, 3), drawing.buffer(program, "e", colors[k], 3)],
            index, count: mesh.faces.length, exposure: 4.0 / peak};
  }).filter(x => x);
}

function daylightItem(drawing, stream) {
  // The faces unwelded (3 vertices each) with their stream position and albedo.
  const gl = drawing.gl, program = compile(gl, DAYLIGHT_VERTEX, DAYLIGHT_FRAGMENT), g = stream.geometry;
  const F = stream.header.faces, p = new Float32Array(9 * F), face = new Float32Array(3 * F), albedo = new Uint8Array(9 * F);
  for (let f = 0; f < F; f++)
    for (let c = 0; c < 3; c++) {
      const v = g.corners[3 * f + c];
      for (let a = 0; a < 3; a++) { p[9 * f + 3 * c + a] = g.points[3 * v + a]; albedo[9 * f + 3 * c + a] = g.albedo[3 * f + a]; }
      face[3 * f + c] = f;
    }
  const albedoBuffer = drawing.buffer(program, "albedo", albedo, 3);
  albedoBuffer.type = gl.UNSIGNED_BYTE;
  albedoBuffer.normalized = true;
  return {program, buffers: [drawing.buffer(program, "p", p, 3), drawing.buffer(program, "face", face, 1), albedoBuffer],
          count: 3 * F, daylight: true, positions: g.points};
}

function contextItem(drawing, context, up) {
  // The scene's triangles that carry no daylight (instances, prims that are not receivers): albedo under a
  // plain light from above, so shadows on the relit faces have their casters beside them.
  const gl = drawing.gl, program = compile(gl, DRAW_VERTEX, DRAW_FRAGMENT), T = context.corners.length / 9;
  const colours = new Float32Array(9 * T), P = context.corners;
  for (let f = 0; f < T; f++) {
    const o = 9 * f, u = [P[o + 3] - P[o], P[o + 4] - P[o + 1], P[o + 5] - P[o + 2]];
    const v = [P[o + 6] - P[o], P[o + 7] - P[o + 1], P[o + 8] - P[o + 2]];
    const shade = 0.5 + 0.4 * dot(normalize(cross(u, v)), up);
    for (let c = 0; c < 3; c++)
      for (let a = 0; a < 3; a++) colours[o + 3 * c + a] = shade * context.albedo[3 * f + a] / 255;
  }
  return {program, buffers: [drawing.buffer(program, "p", context.corners, 3), drawing.buffer(program, "e", colours, 3)],
          count: 3 * T, exposure: 3.0};
}

// ---------------------------------------------------------------------------------------------------------
// The page

async function run() {
  const query = new URLSearchParams(location.search);
  const limit = parseFloat(query.get("limit") || "1");
  const status = document.getElementById("status");
  const canvas = document.getElementById("view");
  if (query.get("fit") !== "0") { canvas.width = Math.max(320, innerWidth); canvas.height = Math.max(240, innerHeight); }
  const drawing = new Drawing(canvas);
  const response = await fetch("/stream" + (query.get("chunk") ? "?chunk=" + encodeURIComponent(query.get("chunk")) : ""));
  const reader = response.body.getReader();
  let pending = new Uint8Array(0), manifest = null, buffers = [], total = 1, received = 0, done = false;
  let daylight = null, daylightIndex = -1, renderer = null, camera = null, dirty = false, playing = false;
  const api = window.usdbake = {relightMs: [], previewMs: [], fullMs: 1e9, firstLitMs: null, ready: false,
                                exposureReference: 1, exposureFixed: false};
  let settle = null, quiet = false, overlay = null, overlayIndex = -1, overlayParts = [];
  const overlayTextures = {};
  const overlayTexture = name => {
    // per face (stream order) values of one annual metric as an R32F texture (unit 7); zeros for none
    const key = name || "";
    if (!overlayTextures[key]) {
      const values = new Float32Array(1024 * renderer.sourceRows);
      if (name) values.set(overlay.metrics[name]);
      overlayTextures[key] = dataTexture(drawing.gl, 7, drawing.gl.R32F, drawing.gl.RED, drawing.gl.FLOAT, 1024, renderer.sourceRows, values);
    }
    return overlayTextures[key];
  };

  const redraw = () => {
    if (!camera) return;
    const controls = readControls();
    drawing.draw(camera, item => {
      const gl = drawing.gl;
      if (item.daylight) {
        gl.activeTexture(gl.TEXTURE4);
        gl.bindTexture(gl.TEXTURE_2D, renderer.target);
        gl.uniform1i(gl.getUniformLocation(item.program, "irradiance"), 4);
        gl.activeTexture(gl.TEXTURE5);
        gl.bindTexture(gl.TEXTURE_2D, renderer.display(renderer.relit));
        gl.uniform1i(gl.getUniformLocation(item.program, "display"), 5);
        gl.uniform1f(gl.getUniformLocation(item.program, "exposure"), controls.exposure * api.exposureReference);
        const shown = overlay && controls.overlay !== "light" ? OVERLAYS[controls.overlay] : null;
        gl.uniform1i(gl.getUniformLocation(item.program, "falseColour"), shown ? 2 : controls.falseColour ? 1 : 0);
        gl.uniform2f(gl.getUniformLocation(item.program, "luxRange"), controls.luxLow, controls.luxHigh);
        gl.uniform2f(gl.getUniformLocation(item.program, "metricRange"), shown ? shown[1] : 0, shown ? shown[2] : 1);
        gl.activeTexture(gl.TEXTURE7);
        gl.bindTexture(gl.TEXTURE_2D, overlayTexture(shown ? controls.overlay : null));
        gl.uniform1i(gl.getUniformLocation(item.program, "overlay"), 7);
      } else {
        gl.uniform1f(gl.getUniformLocation(item.program, "exposure"), item.exposure);
      }
    });
  };
  const previewLimit = () => Math.min(renderer.faces, Math.max(1024, Math.floor(renderer.faces * FRAME_BUDGET_MS / api.fullMs)));
  const relight = (coarse = false) => {
    // new lighting: the relight pass (all faces, or while the controls move a prefix that relights within a
    // frame's budget), then the picture
    const controls = readControls(), chosen = skyFor(controls, daylight.weather);
    const started = performance.now();
    const frame = daylightWeights(daylight, chosen.when, chosen.sky);
    const limit = coarse ? previewLimit() : renderer.faces;
    renderer.relight(frame, limit);
    renderer.finish();
    const spent = performance.now() - started;
    if (limit === renderer.faces) { api.relightMs.push(spent); api.fullMs = Math.max(spent, 1e-3); }
    else api.previewMs.push(spent);
    if (!api.exposureFixed) {  // exposure 0 stops: 1 / the 90th percentile of the radiance's luminance
      const e = renderer.readIrradiance(), albedo = daylight.geometry.albedo, luminance = [];
      for (let f = 0; f < renderer.faces; f++) {
        const y = (0.2126 * albedo[3 * f] * e[3 * f] + 0.7152 * albedo[3 * f + 1] * e[3 * f + 1] + 0.0722 * albedo[3 * f + 2] * e[3 * f + 2]) / (255 * Math.PI);
        if (y > 0) luminance.push(y);
      }
      luminance.sort((a, b) => a - b);
      if (luminance.length) api.exposureReference = 1 / luminance[Math.floor(0.9 * (luminance.length - 1))];
      api.exposureFixed = renderer.received === renderer.faces;
    }
    api.frame = {when: chosen.when, sky: chosen.sky, row: chosen.row, sunZenith: frame.position.zenith,
                 sunAzimuth: frame.position.azimuth};
    document.getElementById("when").textContent = `${formatTime(chosen.when)} local standard time, sun ` +
      (frame.position.zenith < 90 ? `${(90 - frame.position.zenith).toFixed(1)} deg up, azimuth ${frame.position.azimuth.toFixed(0)} deg` : "below the horizon");
    const label = document.getElementById("weatherLabel");
    label.textContent = chosen.row >= 0 ? `row ${chosen.row + 1} of ${daylight.weather.times.length}: ${formatTime(chosen.when)}, ` +
      `DNI ${chosen.sky.directNormal.toFixed(0)} W/m², DHI ${chosen.sky.diffuseHorizontal.toFixed(0)} W/m²` : "";
    const shown = overlay && controls.overlay !== "light" ? OVERLAYS[controls.overlay] : null;
    if (shown) drawLegend(shown[1], shown[2], true); else drawLegend(controls.luxLow, controls.luxHigh);
    document.getElementById("legend").hidden = !shown && !controls.falseColour;
    redraw();
    if (api.firstLitMs === null && renderer.received > 0) api.firstLitMs = performance.now();
  };
  const schedule = (coarse = false) => {
    // one relight per animation frame: a coarse preview while the controls move or the day plays, the whole
    // relight once they rest for SETTLE_MS
    if (quiet) return;
    clearTimeout(settle);
    if (coarse && !playing) settle = setTimeout(() => schedule(false), SETTLE_MS);
    if (dirty) return;
    dirty = true;
    requestAnimationFrame(() => {
      dirty = false;
      if (playing) {
        const hour = document.getElementById("hour");
        hour.value = String((parseFloat(hour.value) + 0.1) % 24);
        schedule(true);
      }
      if (renderer) { renderer.upload(); relight(coarse || playing); } else redraw();
    });
  };
  api.setControls = async values => {
    // set control values as a person would (then the input events), and relight at once (not the preview
    // the events would schedule)
    quiet = true;
    for (const [id, value] of Object.entries(values)) {
      const element = document.getElementById(id);
      if (element.type === "checkbox") element.checked = !!value; else element.value = String(value);
      element.dispatchEvent(new Event("input", {bubbles: true}));
      element.dispatchEvent(new Event("change", {bubbles: true}));
    }
    quiet = false;
    clearTimeout(settle);
    relight();
    return api.frame;
  };
  api.irradiance = () => Array.from(renderer.readIrradiance());
  api.faceId = () => Array.from(daylight.geometry.faceId);
  api.received = () => renderer.received;
  api.contextFaces = () => (daylight.context ? daylight.context.corners.length / 9 : 0);
  api.setCamera = view => {
    // {yaw, pitch (radians), distance (scene units), target [x, y, z]}: any of them; then the picture
    Object.assign(camera, view);
    redraw();
    drawing.gl.finish();
  };
  api.overlay = name => Array.from(overlay.metrics[name]);
  api.probe = (x, y) => {
    // the face under canvas pixel (x, y) and its light: illuminance (179 lm/W), luminance of its Lambertian
    // radiance, the prim it belongs to; shown in the panel (a click does this)
    const [eye, direction] = camera.ray(x, y, canvas.width, canvas.height);
    const g = daylight.geometry, face = pickFace(g.points, g.corners, eye, direction);
    const label = document.getElementById("probe");
    if (face < 0) { label.textContent = ""; return {face, eye, direction}; }
    const shown = renderer.shownFace(face), e = renderer.readFace(shown);
    const luma = c => 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
    const albedo = [0, 1, 2].map(a => g.albedo[3 * face + a] / 255);
    const result = {face, eye, direction, prim: daylight.header.prims[g.prim[face]].path, irradiance: e,
                    lux: LUMINOUS_EFFICACY * luma(e),
                    luminance: LUMINOUS_EFFICACY * luma(e.map((v, a) => v * albedo[a])) / Math.PI};
    label.textContent = `${result.prim}, face ${g.faceId[face]}: ${result.lux.toFixed(0)} lux, ` +
      `${result.luminance.toFixed(1)} cd/m²` + (shown !== face ? " (its ancestor's light: still arriving)" : "");
    return result;
  };
  api.benchmarkRelight = (frames, coarse = false) => {
    // relight `frames` new hours back to back (all faces, or the coarse preview's prefix); per-frame ms of the
    // pass (sky, sun and weights in JavaScript, the shader, the wait for it)
    const controls = readControls(), times = [];
    for (let k = 0; k < frames; k++) {
      const chosen = skyFor({...controls, hour: 6 + 12 * k / frames}, daylight.weather);
      const started = performance.now();
      renderer.relight(daylightWeights(daylight, chosen.when, chosen.sky), coarse ? previewLimit() : renderer.faces);
      renderer.finish();
      times.push(performance.now() - started);
    }
    return {ms: times, faces: coarse ? previewLimit() : renderer.faces};
  };
  for (const id of ["date", "hour", "sky", "turbidity", "dni", "dhi", "sun", "useWeather", "weatherHour", "exposure",
                    "falseColour", "luxLow", "luxHigh", "overlay"])
    document.getElementById(id).addEventListener("input", () => schedule(true));
  document.getElementById("play").addEventListener("click", () => {
    playing = !playing;
    document.getElementById("play").textContent = playing ? "pause" : "play";
    schedule(playing);
  });

  const daylightArrived = async payload => {
    await daylight.push(payload);
    if (!renderer && daylight.geometry && daylight.sky) {
      renderer = new DaylightRenderer(drawing.gl, daylight);
      const item = daylightItem(drawing, daylight);
      drawing.items = [item];
      camera = new OrbitCamera(canvas, matVec(daylight.header.to_world, [0, 0, 1]), bounds([item.positions]), redraw,
                               (x, y) => api.probe(x, y));
      document.getElementById("controls").hidden = false;
      const site = daylight.header.site;
      document.getElementById("site").textContent = `latitude ${site.latitude}, longitude ${site.longitude}, ` +
        `UTC${site.timezone >= 0 ? "+" : ""}${site.timezone}, north ${site.north} deg` +
        (daylight.header.weather ? `, weather ${daylight.header.weather.source}` : "");
    }
    if (renderer && daylight.context && !drawing.items.some(item => item.context)) {
      drawing.items.push({...contextItem(drawing, daylight.context, matVec(daylight.header.to_world, [0, 0, 1])), context: true});
      redraw();
    }
    const weatherControls = document.getElementById("weatherControls");
    if (daylight.weather && weatherControls.hidden) {  // the WEATHER section follows the geometry
      weatherControls.hidden = false;
      document.getElementById("weatherHour").max = String(daylight.weather.times.length - 1);
    }
    if (renderer && daylight.faceSections.length) schedule();
  };

  const overlayArrived = async payload => {
    overlayParts.push(payload);
    const held = overlayParts.reduce((a, p) => a + p.length, 0);
    if (held < manifest.overlay.bytes) return;
    const joined = new Uint8Array(held);
    let at = 0;
    for (const part of overlayParts) { joined.set(part, at); at += part.length; }
    overlay = await decodeOverlay(joined);
    const select = document.getElementById("overlay");
    for (const name of overlay.summary.metrics) {
      const option = document.createElement("option");
      option.value = name;
      option.textContent = OVERLAYS[name] ? OVERLAYS[name][0] : name;
      select.appendChild(option);
    }
    const s = overlay.summary;
    document.getElementById("annual").textContent = "sDA" in s ? `sDA ${(100 * s.sDA).toFixed(1)} %, ASE ${(100 * s.ASE).toFixed(1)} %` : "";
    document.getElementById("overlayControls").hidden = false;
  };

  while (!done) {
    const chunk = await reader.read();
    if (chunk.done) break;
    const joined = new Uint8Array(pending.length + chunk.value.length);
    joined.set(pending); joined.set(chunk.value, pending.length);
    pending = joined;
    while (pending.length >= FRAME_BYTES) {
      const view = new DataView(pending.buffer, pending.byteOffset, pending.byteLength);
      const index = view.getUint32(0, true), length = view.getUint32(4, true);
      if (pending.length < FRAME_BYTES + length) break;
      const payload = pending.slice(FRAME_BYTES, FRAME_BYTES + length);
      pending = pending.slice(FRAME_BYTES + length);
      if (index === 0) {
        manifest = JSON.parse(new TextDecoder().decode(payload));
        const sizes = manifest.meshes.map(m => m.bytes).concat(manifest.grid ? [manifest.grid.bytes] : [])
          .concat(manifest.daylight ? [manifest.daylight.bytes] : []);
        if (manifest.daylight) { daylight = new DaylightStream(manifest.daylight.bytes); daylightIndex = sizes.length; }
        if (manifest.overlay) { sizes.push(manifest.overlay.bytes); overlayIndex = sizes.length; }
        buffers = sizes.map(() => []);
        total = Math.max(1, sizes.reduce((a, b) => a + b, 0));
      } else {
        if (index === daylightIndex) await daylightArrived(payload);
        else if (index === overlayIndex) await overlayArrived(payload);
        else buffers[index - 1].push(payload);
        received += length;
        if (received / total >= limit) { done = true; break; }
      }
    }
  }
  reader.cancel();
  if (daylight) await daylight.work;
  const join = parts => { const out = new Uint8Array(parts.reduce((a, p) => a + p.length, 0)); let o = 0; for (const p of parts) { out.set(p, o); o += p.length; } return out; };
  const meshes = manifest.meshes.map((m, k) => decodeMesh(join(buffers[k])));  // null until header and table
  const grid = manifest.grid ? decodeGrid(join(buffers[manifest.meshes.length])) : null;
  const colors = shade(meshes, grid);
  if (!renderer) {
    drawing.items = drawing.gl ? meshItems(drawing, meshes, colors) : [];
    camera = new OrbitCamera(canvas, [0, 1, 0], bounds(meshes.filter(m => m).map(m => m.positions.subarray(0, 3 * m.level))), redraw);
    if (drawing.gl) redraw();
  } else {
    renderer.upload();
    relight();
  }
  if (drawing.gl) drawing.gl.finish();
  window.usdbakeState = {
    share: received / total, drawn: !!drawing.gl,
    meshes: manifest.meshes.map((m, k) => ({prim: m.prim, level: meshes[k] ? meshes[k].level : 0,
                                            faces: meshes[k] ? Array.from(meshes[k].faces) : [],
                                            irradiance: colors[k] ? Array.from(colors[k]) : []})),
    gridReceived: grid ? grid.received.reduce((a, b) => a + b, 0) : 0,
    daylightFaces: renderer ? renderer.received : 0,
  };
  status.textContent = `${(100 * received / total).toFixed(0)} % of ${total} bytes`;
  api.ready = true;
  document.body.dataset.ready = "1";
}

run().catch(error => { document.getElementById("status").textContent = "error: " + error; document.body.dataset.ready = "error"; });
