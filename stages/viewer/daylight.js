// usdbake daylight in the browser: the daylight stream (formats/daylight_stream.py) decoded as it arrives and
// relit on the GPU for any date, hour, place and sky (Bosch, Besuievsky & Martin, Sec. 5, Eq. 1, with the
// interreflection module's terms; kernels/daylight_relight.py is the library's side):
//
//   E_i = sum_j V_ij w_j + sum_j D_ij (w_j + s_j) + (pi g_i + D^g_i) L_g + cos(n_i, sun) S_i E_sun
//       = sum_j C_ij w_j + sum_{4 sun patches} D_ij s_j + ...,  C = V + D (held as one float32 texture)
//
// w_j: the sky's patch weights, s_j: the sun's direct normal irradiance spread over its 4 nearest patches,
// L_g: the ground's radiance, S_i: the sun table blended bilinearly over declination and hour angle.
// The sky, the sun and these weights come from sky.js once per frame (a few hundred numbers); the sum over
// patches runs per face in a fragment shader that writes each face's irradiance into a float render target
// (one texel per face), which the drawing pass reads. Written here, no third-party code.
"use strict";

const DAYLIGHT_MAGIC = "USDBDLS1";
const SECTION_SKY = 1, SECTION_GEOMETRY = 2, SECTION_WEATHER = 3, SECTION_FACES = 4, SECTION_CONTEXT = 5;
const TEXTURE_WIDTH = 8192;  // texels per row of the coefficient textures at most (WebGL2 guarantees 2048)
const OUT_WIDTH = 256;  // faces per row of the irradiance target

async function inflate(bytes) {
  // zlib (RFC 1950) data, as Python's zlib.compress writes it: the browser's own DecompressionStream("deflate").
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

function typed(bytes, Type, offset, count) {
  // A little-endian array view (copied so it is aligned).
  const size = Type.BYTES_PER_ELEMENT * count;
  return new Type(bytes.slice(offset, offset + size).buffer);
}

class DaylightStream {
  // The stream as it arrives: push() bytes in order; sections are decoded whole, in order.
  constructor(size) {
    this.bytes = new Uint8Array(size);  // the whole stream's size (the manifest's): filled in place, never copied
    this.length = 0;
    this.at = 0;
    this.header = null;
    this.sky = null;
    this.geometry = null;
    this.weather = null;
    this.context = null;  // the scene's other triangles (instances, prims that are not receivers): not relit
    this.received = 0;
    this.faceSections = [];  // decoded FACES sections not yet taken by the renderer
    this.work = Promise.resolve();
  }

  push(chunk) {
    this.bytes.set(chunk.subarray(0, this.bytes.length - this.length), this.length);
    this.length = Math.min(this.bytes.length, this.length + chunk.length);
    this.work = this.work.then(() => this.parse());
    return this.work;
  }

  async parse() {
    const view = new DataView(this.bytes.buffer);
    if (!this.header) {
      if (this.length < 12) return;
      if (new TextDecoder().decode(this.bytes.subarray(0, 8)) !== DAYLIGHT_MAGIC) throw new Error("not a daylight stream");
      const length = view.getUint32(8, true);
      if (this.length < 12 + length) return;
      this.header = JSON.parse(new TextDecoder().decode(this.bytes.subarray(12, 12 + length)));
      setSkyTables(this.header.sky_tables);  // sky.js evaluates the kernels' own tables
      this.at = 12 + length;
    }
    const h = this.header;
    while (this.at + 12 <= this.length) {
      const kind = view.getUint32(this.at, true), count = view.getUint32(this.at + 4, true);
      const size = view.getUint32(this.at + 8, true);
      if (this.at + 12 + size > this.length) return;  // the section is still arriving
      const data = await inflate(this.bytes.subarray(this.at + 12, this.at + 12 + size));
      this.at += 12 + size;
      const n = h.patch_count, F = h.faces, K = h.indirect_sets, R = h.sun_rows;
      let o = 0;
      const take = (Type, length) => { const a = typed(data, Type, o, length); o += Type.BYTES_PER_ELEMENT * length; return a; };
      if (kind === SECTION_SKY) {
        this.sky = {samples: take(Float64Array, n * 27), solidAngles: take(Float64Array, n), directions: take(Float64Array, 3 * n)};
      } else if (kind === SECTION_GEOMETRY) {
        this.geometry = {points: take(Float32Array, 3 * h.points), corners: take(Uint32Array, 3 * F),
                         normals: take(Int16Array, 3 * F), albedo: take(Uint8Array, 3 * F), parent: take(Int32Array, F),
                         faceId: take(Uint32Array, F), prim: take(Uint32Array, F)};
      } else if (kind === SECTION_CONTEXT) {
        this.context = {corners: take(Float32Array, 9 * count), albedo: take(Uint8Array, 3 * count)};
      } else if (kind === SECTION_WEATHER) {
        this.weather = {times: take(Float64Array, count), direct: take(Float32Array, count), diffuse: take(Float32Array, count)};
      } else if (kind === SECTION_FACES) {
        const start = take(Uint32Array, 1)[0];
        this.faceSections.push({start, count, visibility: take(Uint8Array, count * n), indirect: take(Uint8Array, K * count * n),
                                scale: take(Float32Array, K * count), groundDirect: take(Float32Array, count),
                                groundIndirect: take(Float32Array, K * count), sun: take(Uint8Array, count * R)});
        this.received = Math.max(this.received, start + count);
      }
    }
  }
}

function receivedSource(parent, received) {
  // Per stream position, the position whose coefficients it shows: itself when received, else its nearest
  // received ancestor, -1 when none (formats/daylight_stream.received_source).
  const source = new Int32Array(parent.length);
  for (let p = 0; p < parent.length; p++) {
    let s = p;
    while (s >= received) s = parent[s];
    source[p] = s;
  }
  return source;
}

function sunTableNodes(table, declination, hourAngle) {
  // The four (row, weight) pairs SunTable.visibility blends (kernels/daylight_relight.py), rows -1 when unused.
  const decs = table.declinations, K = decs.length, M = table.hour_angles.length;
  let k;
  if (declination <= decs[0]) k = 0;
  else if (declination >= decs[K - 1]) k = K - 1;
  else { let i = 0; while (decs[i + 1] < declination) i++; k = i + (declination - decs[i]) / (decs[i + 1] - decs[i]); }
  k = Math.min(Math.max(k, 0), K - 1 - 1e-9);
  const step = 360 / M;
  const m = ((((hourAngle + 180) % 360) + 360) % 360) / step;
  const k0 = Math.floor(k), m0 = Math.floor(m) % M;
  const out = [];
  for (const [dk, wk] of [[0, 1 - (k - k0)], [1, k - k0]])
    for (const [dm, wm] of [[0, 1 - (m - Math.floor(m))], [1, m - Math.floor(m)]]) {
      const row = table.node_row[Math.min(k0 + dk, K - 1)][(m0 + dm) % M];
      out.push(row >= 0 && wk * wm > 0 ? [row, wk * wm] : [-1, 0]);
    }
  return out;
}

function sunLevels(samples) { return samples * Math.floor(255 / samples); }

function matVec(m, v) { return [0, 1, 2].map(r => m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2]); }

function northTurn(north) {
  // enu_to_world("Z", north): rotation about up, site ENU -> layout ENU.
  const a = north * Math.PI / 180, c = Math.cos(a), s = Math.sin(a);
  return [[c, -s, 0], [s, c, 0], [0, 0, 1]];
}

function daylightWeights(stream, when, sky) {
  // Everything per frame that is not per face: sky.js's models evaluated as Relighter.at does.
  // when: local standard time in ms (Date.UTC of the local clock); sky: {model, turbidity, radiance,
  // directNormal, diffuseHorizontal, efficacy, sun}.
  const h = stream.header, site = h.site, n = h.patch_count;
  const position = sunPosition(when, site.latitude, site.longitude, site.timezone);
  const sunSite = position.enu, sunLayout = matVec(northTurn(site.north), sunSite);
  const day = dayOfYear(when);
  const params = {turbidity: sky.turbidity, radiance: sky.radiance, directNormal: sky.directNormal,
                  diffuseHorizontal: sky.diffuseHorizontal, dayOfYear: day, efficacy: sky.efficacy};
  const weights = skyWeights(stream.sky.samples, stream.sky.solidAngles, sky.model, sunLayout, params);
  const eNormal = sky.sun ? sunNormal(sky.model, sunSite, params) : null;
  const sunPatches = [];  // [patch, rgb]: the sun's direct normal irradiance spread over its nearest patches
  if (eNormal) {
    const s = sunPatchWeights(stream.sky.directions, sunLayout, eNormal);
    for (let j = 0; j < n; j++) if (s[3 * j] || s[3 * j + 1] || s[3 * j + 2]) sunPatches.push([j, [s[3 * j], s[3 * j + 1], s[3 * j + 2]]]);
  }
  if (!stream.cosines) stream.cosines = horizontalCosines(stream.sky.samples, n);
  const ground = groundRadiance(stream.cosines, weights, sunLayout, eNormal, h.ground_reflectance);
  const sunWorld = matVec(h.to_world, sunLayout);
  const nodes = eNormal ? sunTableNodes(h.sun_table, position.declination, position.hourAngle) : [];
  return {weights, sunPatches, ground, eNormal, sunWorld, nodes, position};
}

function compile(gl, vertex, fragment) {
  const program = gl.createProgram();
  for (const [type, source] of [[gl.VERTEX_SHADER, vertex], [gl.FRAGMENT_SHADER, fragment]]) {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
    gl.attachShader(program, shader);
  }
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  return program;
}

function dataTexture(gl, unit, internal, format, type, width, height, data) {
  const texture = gl.createTexture();
  gl.activeTexture(gl.TEXTURE0 + unit);
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.texImage2D(gl.TEXTURE_2D, 0, internal, width, height, 0, format, type, data);
  for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
  return texture;
}

class DaylightRenderer {
  // GPU side: coefficient textures filled as FACES sections arrive, a relight pass into a float target.
  constructor(gl, stream) {
    const h = stream.header;
    this.gl = gl;
    this.stream = stream;
    this.faces = h.faces;
    this.K = h.indirect_sets;
    this.quads = Math.ceil(h.patch_count / 4);  // texels per coefficient set and face, 4 patches each
    this.perFace = this.quads * this.K;
    if (!gl.getExtension("EXT_color_buffer_float")) throw new Error("WebGL2 without float render targets");
    const limit = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    this.width = Math.min(limit, TEXTURE_WIDTH);
    this.facesPerRow = Math.floor(this.width / this.perFace);
    const rows = Math.ceil(this.faces / this.facesPerRow);
    if (rows > limit) throw new Error(`${this.faces} faces need ${rows} texture rows; this GPU allows ${limit}`);
    // C = V + D per set (float32: the sky's light direct and bounced in one sum), and D's own codes for the
    // sun's 4 patches (its light only bounces: E_sun keeps the sun table)
    this.combined = dataTexture(gl, 0, gl.RGBA32F, gl.RGBA, gl.FLOAT, this.facesPerRow * this.perFace, rows, null);
    this.indirectCodes = dataTexture(gl, 6, gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, this.facesPerRow * this.perFace, rows, null);
    // per face: (normal, pi g), (D^g per set, received), (D scale per set, 0)
    this.faceRows = Math.ceil(this.faces / 1024);
    this.faceData = new Float32Array(1024 * this.faceRows * 12);
    const g = stream.geometry;
    for (let f = 0; f < this.faces; f++)
      for (let a = 0; a < 3; a++) this.faceData[12 * f + a] = g.normals[3 * f + a] / 32767;
    this.perFaceTexture = dataTexture(gl, 1, gl.RGBA32F, gl.RGBA, gl.FLOAT, 3 * 1024, this.faceRows, this.faceData);
    this.R = Math.max(1, h.sun_rows);
    this.sunQuads = Math.ceil(this.R / 4);  // RGBA8 texels of sun table shares per face
    this.sunPerRow = Math.floor(this.width / this.sunQuads);
    const sunRows = Math.ceil(this.faces / this.sunPerRow);
    if (sunRows > limit) throw new Error(`${this.faces} faces need ${sunRows} texture rows of sun table; this GPU allows ${limit}`);
    this.sun = dataTexture(gl, 2, gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, this.sunPerRow * this.sunQuads, sunRows, null);
    this.sourceRows = Math.ceil(this.faces / 1024);
    this.source = dataTexture(gl, 3, gl.R32I, gl.RED_INTEGER, gl.INT, 1024, this.sourceRows, null);
    this.outRows = Math.ceil(this.faces / OUT_WIDTH);
    this.target = dataTexture(gl, 4, gl.RGBA32F, gl.RGBA, gl.FLOAT, OUT_WIDTH, this.outRows, null);
    this.framebuffer = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.framebuffer);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, this.target, 0);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    this.program = compile(gl, `#version 300 es
      void main() { vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2); gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0); }`,
      this.relightShader());
    this.weights = gl.createBuffer();
    gl.bindBuffer(gl.UNIFORM_BUFFER, this.weights);
    gl.bufferData(gl.UNIFORM_BUFFER, 4 * 4 * this.quads * 3, gl.DYNAMIC_DRAW);
    gl.uniformBlockBinding(this.program, gl.getUniformBlockIndex(this.program, "Weights"), 0);
    this.received = 0;
  }

  relightShader() {
    // One fragment per face, Eq. 1 with the interreflection's terms: E = sum_j C_ij w_j + sum_{4 sun patches}
    // D_ij s_j + ground + sun, C = V + D (float32, 4 patches per texel), D = s (code / 255)^2 (square-root codes).
    const Q = this.quads, K = this.K;
    const sky = K === 1 ? `
        for (int t = 0; t < ${Q}; t++) {
          vec4 c = texelFetch(combined, ivec2(base + t, row), 0);
          e += vec3(dot(c, wr[t]), dot(c, wg[t]), dot(c, wb[t]));
        }` : `
        for (int t = 0; t < ${Q}; t++) {
          e += vec3(dot(texelFetch(combined, ivec2(base + t, row), 0), wr[t]),
                    dot(texelFetch(combined, ivec2(base + ${Q} + t, row), 0), wg[t]),
                    dot(texelFetch(combined, ivec2(base + ${2 * Q} + t, row), 0), wb[t]));
        }`;
    const sunPatch = (k, channels) => `
            { float d = texelFetch(indirectCodes, ivec2(base + ${k * Q} + j / 4, row), 0)[j % 4];
              e${channels} += scales[${k}] * d * d * sunPatchLight[q]${channels}; }`;
    const bounced = K === 1 ? sunPatch(0, "") : sunPatch(0, ".r") + sunPatch(1, ".g") + sunPatch(2, ".b");
    return `#version 300 es
      precision highp float; precision highp int;
      uniform highp sampler2D combined;
      uniform highp sampler2D indirectCodes;
      uniform highp sampler2D perFace;
      uniform highp sampler2D sunShares;
      uniform highp isampler2D source;
      layout(std140) uniform Weights { vec4 wr[${Q}]; vec4 wg[${Q}]; vec4 wb[${Q}]; };
      uniform int faces;
      uniform vec3 ground;
      uniform ivec4 sunPatches;
      uniform vec3 sunPatchLight[4];
      uniform vec3 sunDirection;
      uniform vec3 sunIrradiance;
      uniform ivec4 sunRows;
      uniform vec4 sunWeights;
      out vec4 irradiance;
      void main() {
        int face = int(gl_FragCoord.y) * ${OUT_WIDTH} + int(gl_FragCoord.x);
        irradiance = vec4(0.0);
        if (face >= faces) return;
        int s = texelFetch(source, ivec2(face % 1024, face / 1024), 0).r;
        if (s < 0) return;
        int row = s / ${this.facesPerRow};
        int base = (s - row * ${this.facesPerRow}) * ${this.perFace};
        vec3 e = vec3(0.0);
        ${sky}
        vec4 own = texelFetch(perFace, ivec2(3 * (face % 1024), face / 1024), 0);
        vec4 groundTerms = texelFetch(perFace, ivec2(3 * (s % 1024) + 1, s / 1024), 0);
        vec4 scales = texelFetch(perFace, ivec2(3 * (s % 1024) + 2, s / 1024), 0);
        for (int q = 0; q < 4; q++) {
          int j = sunPatches[q];
          if (j >= 0) ${bounced}
        }
        float g = texelFetch(perFace, ivec2(3 * (s % 1024), s / 1024), 0).w;
        e += (vec3(g) + ${K === 1 ? "vec3(groundTerms.x)" : "groundTerms.xyz"}) * ground;
        float cosine = max(dot(own.xyz, sunDirection), 0.0);
        if (cosine > 0.0) {
          int sunRow = s / ${this.sunPerRow};
          int sunBase = (s - sunRow * ${this.sunPerRow}) * ${this.sunQuads};
          float seen = 0.0;
          for (int q = 0; q < 4; q++)
            if (sunRows[q] >= 0) seen += sunWeights[q] * texelFetch(sunShares, ivec2(sunBase + sunRows[q] / 4, sunRow), 0)[sunRows[q] % 4];
          e += cosine * seen * sunIrradiance;
        }
        irradiance = vec4(e, 1.0);
      }`;
  }

  upload() {
    // Take the FACES sections decoded since the last call into the textures; update each face's source.
    const gl = this.gl, stream = this.stream, h = stream.header, n = h.patch_count, K = this.K, Q = this.quads;
    const sections = stream.faceSections.splice(0);
    if (!sections.length) return false;
    for (const section of sections) {
      const count = section.count, vScale = h.visibility_scale;
      const codes = new Uint8Array(count * this.perFace * 4), sums = new Float32Array(count * this.perFace * 4);
      for (let i = 0; i < count; i++)
        for (let k = 0; k < K; k++) {
          const o = (i * K + k) * 4 * Q, d = (k * count + i) * n, scale = section.scale[k * count + i] / (255 * 255);
          const green = (count + i) * n;  // three sets come as G and R - G, B - G modulo 256
          for (let j = 0; j < n; j++) {
            const c = K === 3 && k !== 1 ? (section.indirect[d + j] + section.indirect[green + j]) & 255 : section.indirect[d + j];
            codes[o + j] = c;
            sums[o + j] = section.visibility[i * n + j] * vScale + c * c * scale;
          }
        }
      // whole rows of the coefficient texture: sections start at multiples of packet_faces, not of facesPerRow
      for (let i = 0; i < count;) {
        const face = section.start + i, row = Math.floor(face / this.facesPerRow), column = face % this.facesPerRow;
        const span = Math.min(this.facesPerRow - column, count - i);
        gl.activeTexture(gl.TEXTURE0);
        gl.bindTexture(gl.TEXTURE_2D, this.combined);
        gl.texSubImage2D(gl.TEXTURE_2D, 0, column * this.perFace, row, span * this.perFace, 1, gl.RGBA, gl.FLOAT,
                         sums.subarray(i * this.perFace * 4, (i + span) * this.perFace * 4));
        gl.activeTexture(gl.TEXTURE6);
        gl.bindTexture(gl.TEXTURE_2D, this.indirectCodes);
        gl.texSubImage2D(gl.TEXTURE_2D, 0, column * this.perFace, row, span * this.perFace, 1, gl.RGBA, gl.UNSIGNED_BYTE,
                         codes.subarray(i * this.perFace * 4, (i + span) * this.perFace * 4));
        const sun = section.sun.subarray(i * this.R, (i + span) * this.R);
        gl.activeTexture(gl.TEXTURE2);
        gl.bindTexture(gl.TEXTURE_2D, this.sun);
        // the sun texture holds another number of faces per row than the coefficients: runs of its own rows
        for (let j = 0; j < span;) {
          const f = face + j, r = Math.floor(f / this.sunPerRow), c = f % this.sunPerRow;
          const run = Math.min(this.sunPerRow - c, span - j);
          const padded = new Uint8Array(run * this.sunQuads * 4);
          for (let q = 0; q < run; q++) padded.set(sun.subarray((j + q) * this.R, (j + q + 1) * this.R), q * this.sunQuads * 4);
          gl.texSubImage2D(gl.TEXTURE_2D, 0, c * this.sunQuads, r, run * this.sunQuads, 1, gl.RGBA, gl.UNSIGNED_BYTE, padded);
          j += run;
        }
        i += span;
      }
      for (let i = 0; i < count; i++) {
        const f = section.start + i, o = 12 * f;
        this.faceData[o + 3] = section.groundDirect[i];
        for (let k = 0; k < K; k++) {
          this.faceData[o + 4 + k] = section.groundIndirect[k * count + i];
          this.faceData[o + 8 + k] = section.scale[k * count + i];
        }
        this.faceData[o + 7] = 1;
      }
      this.received = Math.max(this.received, section.start + count);
    }
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, this.perFaceTexture);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 3 * 1024, this.faceRows, gl.RGBA, gl.FLOAT, this.faceData);
    const source = new Int32Array(1024 * this.sourceRows).fill(-1);
    source.set(receivedSource(stream.geometry.parent, this.received));
    gl.activeTexture(gl.TEXTURE3);
    gl.bindTexture(gl.TEXTURE_2D, this.source);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 1024, this.sourceRows, gl.RED_INTEGER, gl.INT, source);
    return true;
  }

  relight(frame, limit = this.faces) {
    // The relight pass for daylightWeights' ``frame``, of stream positions [0, limit) (the coarse faces first:
    // an interactive preview relights a prefix and shows the rest with their ancestors' light, ``display``);
    // leaves the irradiance in the target texture (unit 4).
    const gl = this.gl, h = this.stream.header, Q = this.quads, n = h.patch_count;
    const block = new Float32Array(4 * Q * 3);
    for (let j = 0; j < n; j++)
      for (let c = 0; c < 3; c++) block[c * 4 * Q + j] = frame.weights[3 * j + c];
    const patches = [-1, -1, -1, -1], light = new Float32Array(12);
    frame.sunPatches.forEach(([j, rgb], q) => { patches[q] = j; light.set(rgb, 3 * q); });
    gl.useProgram(this.program);
    gl.bindBuffer(gl.UNIFORM_BUFFER, this.weights);
    gl.bufferSubData(gl.UNIFORM_BUFFER, 0, block);
    gl.bindBufferBase(gl.UNIFORM_BUFFER, 0, this.weights);
    const units = [["combined", this.combined, 0], ["perFace", this.perFaceTexture, 1], ["sunShares", this.sun, 2],
                   ["source", this.source, 3], ["indirectCodes", this.indirectCodes, 6]];
    for (const [name, texture, unit] of units) {
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(gl.TEXTURE_2D, texture);
      gl.uniform1i(gl.getUniformLocation(this.program, name), unit);
    }
    gl.uniform4iv(gl.getUniformLocation(this.program, "sunPatches"), patches);
    gl.uniform3fv(gl.getUniformLocation(this.program, "sunPatchLight"), light);
    gl.uniform1i(gl.getUniformLocation(this.program, "faces"), limit);
    gl.uniform3fv(gl.getUniformLocation(this.program, "ground"), frame.ground);
    const e = frame.eNormal || [0, 0, 0];
    gl.uniform3fv(gl.getUniformLocation(this.program, "sunDirection"), frame.sunWorld);
    gl.uniform3fv(gl.getUniformLocation(this.program, "sunIrradiance"), e);
    const levels = sunLevels(h.sun_table.samples);
    const nodes = frame.nodes.length ? frame.nodes : [[-1, 0], [-1, 0], [-1, 0], [-1, 0]];
    gl.uniform4iv(gl.getUniformLocation(this.program, "sunRows"), nodes.map(x => x[0]));
    // shares are bytes / 255 in the shader; the table's steps are 1 / levels
    gl.uniform4fv(gl.getUniformLocation(this.program, "sunWeights"), nodes.map(x => x[1] * 255 / levels));
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.framebuffer);
    gl.viewport(0, 0, OUT_WIDTH, Math.ceil(limit / OUT_WIDTH));
    this.relit = limit;
    gl.disable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  }

  display(limit) {
    // Per face, the stream position whose irradiance it shows after a relight of [0, limit): itself, or its
    // nearest ancestor below the limit; a texture (unit 5) the drawing reads.
    const gl = this.gl;
    if (!this.displayTexture) this.displayTexture = dataTexture(gl, 5, gl.R32I, gl.RED_INTEGER, gl.INT, 1024, this.sourceRows, null);
    if (this.displayLimit !== limit) {
      const shown = new Int32Array(1024 * this.sourceRows);
      shown.set(receivedSource(this.stream.geometry.parent, limit));
      gl.activeTexture(gl.TEXTURE5);
      gl.bindTexture(gl.TEXTURE_2D, this.displayTexture);
      gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 1024, this.sourceRows, gl.RED_INTEGER, gl.INT, shown);
      this.displayLimit = limit;
    }
    return this.displayTexture;
  }

  shownFace(face) {
    // the stream position whose irradiance face shows after the last relight (itself, or an ancestor)
    let f = face;
    while (f >= 0 && f >= Math.min(this.received, this.relit)) f = this.stream.geometry.parent[f];
    return f;
  }

  readFace(face) {
    // [r, g, b] irradiance of one stream position from the render target ([0, 0, 0] for -1)
    if (face < 0) return [0, 0, 0];
    const gl = this.gl, texel = new Float32Array(4);
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.framebuffer);
    gl.readPixels(face % OUT_WIDTH, Math.floor(face / OUT_WIDTH), 1, 1, gl.RGBA, gl.FLOAT, texel);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    return [texel[0], texel[1], texel[2]];
  }

  finish() {
    // Wait for the relight pass: read one texel back (a readPixels waits for the GPU).
    const gl = this.gl, texel = new Float32Array(4);
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.framebuffer);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.FLOAT, texel);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  }

  readIrradiance() {
    // (F * 3) per-face irradiance in stream order, read back from the render target.
    const gl = this.gl, all = new Float32Array(OUT_WIDTH * this.outRows * 4);
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.framebuffer);
    gl.readPixels(0, 0, OUT_WIDTH, this.outRows, gl.RGBA, gl.FLOAT, all);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    const out = new Float32Array(3 * this.faces);
    for (let f = 0; f < this.faces; f++) for (let c = 0; c < 3; c++) out[3 * f + c] = all[4 * f + c];
    return out;
  }
}
