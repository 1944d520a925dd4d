// usdbake viewer: the orbit camera (drag: turn, shift-drag or right-drag: pan, wheel: zoom) about the scene's
// up axis, and a perspective view-projection matrix for WebGL. Written here, no third-party code.
"use strict";

const FIELD_OF_VIEW = 0.9;  // radians, vertical

function bounds(positionArrays) {
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (const p of positionArrays) for (let i = 0; i < p.length; i++) {
    lo[i % 3] = Math.min(lo[i % 3], p[i]); hi[i % 3] = Math.max(hi[i % 3], p[i]);
  }
  if (!(lo[0] <= hi[0])) return {centre: [0, 0, 0], radius: 1};
  return {centre: lo.map((x, a) => (x + hi[a]) / 2), radius: Math.max(1e-6, Math.hypot(...hi.map((x, a) => x - lo[a])) / 2)};
}

function normalize(v) { const l = Math.hypot(v[0], v[1], v[2]) || 1; return v.map(x => x / l); }
function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

class OrbitCamera {
  // Yaw and pitch about the scene's up axis around a target, at a distance; a perspective projection.
  constructor(canvas, up, box, onChange, onPick = () => {}) {
    this.up = normalize(up);
    const helper = Math.abs(this.up[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0];
    this.east = normalize(cross(helper, this.up));
    this.north = cross(this.up, this.east);
    this.target = box.centre.slice();
    this.radius = box.radius;
    this.distance = 2.6 * box.radius;
    this.yaw = 0.785;  // a three-quarter view, as the fixed view before it
    this.pitch = 0.45;
    let last = null, panning = false, moved = 0;
    canvas.addEventListener("contextmenu", event => event.preventDefault());
    canvas.addEventListener("pointerdown", event => {
      last = [event.clientX, event.clientY]; panning = event.shiftKey || event.button === 2; moved = 0;
      canvas.setPointerCapture(event.pointerId);
    });
    canvas.addEventListener("pointerup", event => {
      last = null;
      if (moved < 4 && event.button === 0) {  // a click, not a drag: pick what is under it
        const box = canvas.getBoundingClientRect();
        onPick(event.clientX - box.left, event.clientY - box.top);
      }
    });
    canvas.addEventListener("pointermove", event => {
      if (!last) return;
      const dx = event.clientX - last[0], dy = event.clientY - last[1];
      moved += Math.abs(dx) + Math.abs(dy);
      last = [event.clientX, event.clientY];
      if (panning) this.pan(dx, dy); else this.turn(dx, dy);
      onChange();
    });
    canvas.addEventListener("wheel", event => { event.preventDefault(); this.zoom(Math.exp(0.001 * event.deltaY)); onChange(); },
                            {passive: false});
  }

  turn(dx, dy) {
    this.yaw -= 0.008 * dx;
    this.pitch = Math.min(1.55, Math.max(-1.55, this.pitch + 0.008 * dy));
  }

  zoom(factor) { this.distance = Math.min(50 * this.radius, Math.max(0.01 * this.radius, this.distance * factor)); }

  pan(dx, dy) {
    const [, right, upward] = this.frame(), step = this.distance * 0.0015;
    for (let a = 0; a < 3; a++) this.target[a] += step * (-dx * right[a] + dy * upward[a]);
  }

  frame() {
    // eye position, and the view's right and up directions
    const c = Math.cos(this.pitch), offset = [0, 1, 2].map(a =>
      this.distance * (c * Math.cos(this.yaw) * this.east[a] + c * Math.sin(this.yaw) * this.north[a] + Math.sin(this.pitch) * this.up[a]));
    const eye = this.target.map((x, a) => x + offset[a]);
    const forward = normalize(offset.map(x => -x));
    const right = normalize(cross(forward, this.up));
    return [eye, right, cross(right, forward), forward];
  }

  ray(x, y, width, height) {
    // [eye, unit direction] through pixel (x, y) of a width x height view (the projection of matrix())
    const [eye, right, upward, forward] = this.frame(), f = 1 / Math.tan(0.5 * FIELD_OF_VIEW);
    const u = (2 * (x + 0.5) / width - 1) * (width / height) / f, v = (1 - 2 * (y + 0.5) / height) / f;
    return [eye, normalize([0, 1, 2].map(a => forward[a] + u * right[a] + v * upward[a]))];
  }

  matrix(aspect) {
    // column-major view-projection for WebGL
    const [eye, right, upward, forward] = this.frame();
    const near = Math.max(1e-4 * this.radius, this.distance - 4 * this.radius, 0.005 * this.distance);
    const far = this.distance + 4 * this.radius, f = 1 / Math.tan(0.5 * FIELD_OF_VIEW);
    const view = [right, upward, forward.map(x => -x)];
    const translation = view.map(row => -dot(row, eye));
    const m = new Float32Array(16);
    for (let col = 0; col < 3; col++) {
      m[4 * col + 0] = f / aspect * view[0][col];
      m[4 * col + 1] = f * view[1][col];
      m[4 * col + 2] = (far + near) / (near - far) * view[2][col];
      m[4 * col + 3] = -view[2][col];
    }
    m[12] = f / aspect * translation[0];
    m[13] = f * translation[1];
    m[14] = (far + near) / (near - far) * translation[2] + 2 * far * near / (near - far);
    m[15] = -translation[2];
    return m;
  }
}

function pickFace(points, corners, eye, direction) {
  // The nearest face whose front (counter-clockwise, as drawn) the ray meets: Moller-Trumbore over every face,
  // -1 for none. A click's pick, not a frame's work: a plain loop is a few ms at 100k faces.
  let best = -1, nearest = Infinity;
  for (let f = 0; f < corners.length / 3; f++) {
    const a = 3 * corners[3 * f], b = 3 * corners[3 * f + 1], c = 3 * corners[3 * f + 2];
    const e1 = [points[b] - points[a], points[b + 1] - points[a + 1], points[b + 2] - points[a + 2]];
    const e2 = [points[c] - points[a], points[c + 1] - points[a + 1], points[c + 2] - points[a + 2]];
    const p = cross(direction, e2), det = dot(e1, p);
    if (!(det > 1e-20)) continue;  // det = -n . d (n = e1 x e2): the back or the edge of a one-sided face
    const s = [eye[0] - points[a], eye[1] - points[a + 1], eye[2] - points[a + 2]];
    const u = dot(s, p) / det;
    if (u < 0 || u > 1) continue;
    const q = cross(s, e1), v = dot(direction, q) / det;
    if (v < 0 || u + v > 1) continue;
    const t = dot(e2, q) / det;
    if (t > 0 && t < nearest) { nearest = t; best = f; }
  }
  return best;
}
