// usdbake stream viewer: reads GET /stream (stages/serve.py) and draws the scene as it arrives.
//
// Written here, no third-party code: the frame parser, the two stream decoders (formats/mesh_stream.py and
// formats/streaming.py, little-endian), the level-of-detail mapping of Pacanowski et al. 2008 section 4.2,
// the grid reconstruction of section 3.2 (I_n = sum_a n_a^2 I_a, E = max(0, I_n . n)) and a WebGL2 drawing.
// Grid vertices not received yet are left out of the trilinear weights (the Python client fills them by
// push-pull instead); with the whole stream both read the same vectors.
//
// ?limit=F stops reading after that share of the stream bytes (the browser test's checkpoints); ?chunk=N asks
// the server for N-byte frames.
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

function draw(canvas, meshes, colors) {
  const gl = canvas.getContext("webgl2");
  if (!gl) return false;
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (const m of meshes) if (m) for (let i = 0; i < m.positions.length; i++) {
    lo[i % 3] = Math.min(lo[i % 3], m.positions[i]); hi[i % 3] = Math.max(hi[i % 3], m.positions[i]);
  }
  const centre = lo.map((x, a) => (x + hi[a]) / 2), radius = Math.max(1e-6, Math.hypot(...hi.map((x, a) => x - lo[a])) / 2);
  let peak = 1e-12;
  for (const c of colors) if (c) for (const x of c) peak = Math.max(peak, x);
  const program = gl.createProgram();
  for (const [type, source] of [[gl.VERTEX_SHADER, `#version 300 es
      in vec3 p; in vec3 e; uniform vec3 centre; uniform float radius; out vec3 colour;
      void main() {
        vec3 q = (p - centre) / radius;
        float c = 0.7071, s = 0.7071;  // a three-quarter view: turn about y, then tilt
        vec3 r = vec3(c * q.x + s * q.z, q.y, -s * q.x + c * q.z);
        r = vec3(r.x, 0.9 * r.y - 0.43 * r.z, 0.43 * r.y + 0.9 * r.z);
        gl_Position = vec4(0.8 * r.x, 0.8 * r.y, -0.5 * r.z, 1.0);
        colour = e;
      }`], [gl.FRAGMENT_SHADER, `#version 300 es
      precision highp float; in vec3 colour; uniform float exposure; out vec4 outColour;
      void main() { vec3 x = colour * exposure; outColour = vec4(x / (1.0 + x), 1.0); }`]]) {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    gl.attachShader(program, shader);
  }
  gl.linkProgram(program);
  gl.useProgram(program);
  gl.uniform3fv(gl.getUniformLocation(program, "centre"), centre);
  gl.uniform1f(gl.getUniformLocation(program, "radius"), radius);
  gl.uniform1f(gl.getUniformLocation(program, "exposure"), 4.0 / peak);
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.clearColor(0.08, 0.08, 0.1, 1);
  gl.enable(gl.DEPTH_TEST);
  gl.enable(gl.CULL_FACE);  // one-sided, as the baker's surfaces: a room's near walls open onto its inside
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  meshes.forEach((mesh, k) => {
    if (!mesh || !mesh.faces.length) return;
    for (const [name, data] of [["p", mesh.positions], ["e", colors[k]]]) {
      const buffer = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
      gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
      const location = gl.getAttribLocation(program, name);
      gl.enableVertexAttribArray(location);
      gl.vertexAttribPointer(location, 3, gl.FLOAT, false, 0, 0);
    }
    const index = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, index);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, mesh.faces, gl.STATIC_DRAW);
    gl.drawElements(gl.TRIANGLES, mesh.faces.length, gl.UNSIGNED_INT, 0);
  });
  gl.finish();
  return true;
}

async function run() {
  const query = new URLSearchParams(location.search);
  const limit = parseFloat(query.get("limit") || "1");
  const status = document.getElementById("status");
  const response = await fetch("/stream" + (query.get("chunk") ? "?chunk=" + encodeURIComponent(query.get("chunk")) : ""));
  const reader = response.body.getReader();
  let pending = new Uint8Array(0), manifest = null, buffers = [], total = 1, received = 0, done = false;
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
        const sizes = manifest.meshes.map(m => m.bytes).concat(manifest.grid ? [manifest.grid.bytes] : []);
        buffers = sizes.map(() => []);
        total = Math.max(1, sizes.reduce((a, b) => a + b, 0));
      } else {
        buffers[index - 1].push(payload);
        received += length;
        if (received / total >= limit) { done = true; break; }
      }
    }
  }
  reader.cancel();
  const join = parts => { const out = new Uint8Array(parts.reduce((a, p) => a + p.length, 0)); let o = 0; for (const p of parts) { out.set(p, o); o += p.length; } return out; };
  const meshes = manifest.meshes.map((m, k) => decodeMesh(join(buffers[k])));  // null until header and table
  const grid = manifest.grid ? decodeGrid(join(buffers[buffers.length - 1])) : null;
  const colors = shade(meshes, grid);
  const drawn = draw(document.getElementById("view"), meshes, colors);
  window.usdbakeState = {
    share: received / total, drawn,
    meshes: manifest.meshes.map((m, k) => ({prim: m.prim, level: meshes[k] ? meshes[k].level : 0,
                                            faces: meshes[k] ? Array.from(meshes[k].faces) : [],
                                            irradiance: colors[k] ? Array.from(colors[k]) : []})),
    gridReceived: grid ? grid.received.reduce((a, b) => a + b, 0) : 0,
  };
  status.textContent = `${(100 * received / total).toFixed(0)} % of ${total} bytes`;
  document.body.dataset.ready = "1";
}

run().catch(error => { document.getElementById("status").textContent = "error: " + error; document.body.dataset.ready = "error"; });
