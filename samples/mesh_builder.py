"""Polygon building blocks of the sample stages: pure numpy geometry and MeshBuilder.

Nothing here touches USD; stage_authoring.write_mesh turns a MeshBuilder into a UsdGeom.Mesh.
Faces wind counter-clockwise seen from the side they face (USD's rightHanded default).
"""

import numpy as np

X, Y, Z = np.eye(3)

# Tangent axes (b, c) of each box face, ordered so that e_b x e_c is the outward normal.
BOX_FACE_AXES = {"+x": (1, 2), "-x": (2, 1), "+y": (2, 0), "-y": (0, 2), "+z": (0, 1), "-z": (1, 0)}
ALL_FACES = tuple(BOX_FACE_AXES)


def faces_except(*left_out):
    """The box faces in ALL_FACES order without `left_out` (e.g. "-y": a box resting on the ground, Y-up)."""
    return tuple(face for face in ALL_FACES if face not in left_out)


def unit(vector):
    """The vector scaled to length 1."""
    vector = np.asarray(vector, dtype=float)
    return vector / np.linalg.norm(vector)


def newell_normal(points):
    """Unnormalised normal of a (possibly concave) polygon, by Newell's method."""
    points = np.asarray(points, dtype=float)
    return np.cross(points, np.roll(points, -1, axis=0)).sum(axis=0)


def area_from_above(outline_xz):
    """Signed area of an (x, z) outline: positive when counter-clockwise seen from +Y."""
    x, z = np.asarray(outline_xz, dtype=float).T
    return -0.5 * np.sum(x * np.roll(z, -1) - np.roll(x, -1) * z)


def ticks(stops, step=None):
    """Values from stops[0] to stops[-1] through every stop, at most ~step apart (None: just the stops)."""
    values = [float(stops[0])]
    for start, stop in zip(stops[:-1], stops[1:]):
        count = 1 if step is None else max(1, int(np.ceil((stop - start) / step - 1e-9)))
        values.extend(np.linspace(start, stop, count + 1)[1:])
    return np.array(values)


def lattice_quads(nu, nv, wrap=False):
    """(n, 4) vertex indices of the quads of a row-major nu x nv lattice, cell (i, j) at row i*(nv-1)+j."""
    i, j = np.meshgrid(np.arange(nu if wrap else nu - 1), np.arange(nv - 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1 = (i + 1) % nu
    return np.stack([i * nv + j, i1 * nv + j, i1 * nv + j + 1, i * nv + j + 1], axis=1)


def bilinear_patch(corners, nu, nv):
    """(nu+1, nv+1, 3) lattice spanning a quad given as 4 corners in winding order."""
    c0, c1, c2, c3 = np.asarray(corners, dtype=float)
    s = np.linspace(0, 1, nu + 1)[:, None, None]
    t = np.linspace(0, 1, nv + 1)[None, :, None]
    return (1 - s) * (1 - t) * c0 + s * (1 - t) * c1 + s * t * c2 + (1 - s) * t * c3


def icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: (P, 3) float64 points, (T, 3) int32 outward-wound triangles (20 * 4^level)."""
    t = (1 + 5 ** 0.5) / 2
    points = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
              (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    points = [np.array(p, float) / np.linalg.norm(p) for p in points]
    for _ in range(level):
        cache, new_faces = {}, []

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = points[a] + points[b]
                points.append(m / np.linalg.norm(m))
                cache[key] = len(points) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return np.array(points), np.array(faces, np.int32)


class MeshBuilder:
    """Accumulates polygons for one UsdGeom.Mesh."""

    def __init__(self):
        self._points, self._counts, self._indices = [], [], []
        self._num_points = 0

    def add(self, points, counts, indices):
        """Append vertices and faces whose indices refer to `points`."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        self._points.append(points)
        self._counts.append(np.asarray(counts, dtype=np.int32).ravel())
        self._indices.append(np.asarray(indices, dtype=np.int32).ravel() + self._num_points)
        self._num_points += len(points)

    def arrays(self):
        """(points, faceVertexCounts, faceVertexIndices) as numpy arrays."""
        return np.vstack(self._points), np.concatenate(self._counts), np.concatenate(self._indices)

    def extend(self, other, axes=np.eye(3), origin=(0, 0, 0)):
        """Append another builder's faces; local x, y, z map to the rows of `axes` (a rotation), then move."""
        points, counts, indices = other.arrays()
        self.add(points @ np.asarray(axes) + origin, counts, indices)

    def polygon(self, points, facing=None):
        """One face with its own vertices, reversed if its normal opposes `facing`."""
        points = np.asarray(points, dtype=float)
        if facing is not None and np.dot(newell_normal(points), facing) < 0:
            points = points[::-1]
        self.add(points, [len(points)], np.arange(len(points)))

    def lattice(self, points, skip=()):
        """Quads over an (nu, nv, 3) lattice sharing vertices (normal d/du x d/dv); skip: cells (i, j) left out."""
        nu, nv = points.shape[:2]
        quads = lattice_quads(nu, nv)
        keep = np.ones(len(quads), dtype=bool)
        keep[[i * (nv - 1) + j for i, j in skip]] = False
        used, local = np.unique(quads[keep], return_inverse=True)
        self.add(points.reshape(-1, 3)[used], np.full(keep.sum(), 4), local)

    def grid(self, origin, u, v, u_ticks, v_ticks, skip=()):
        """Planar quad grid at origin + u*s + v*t for the tick values s, t (normal u x v)."""
        s = np.asarray(u_ticks, dtype=float)[:, None, None]
        t = np.asarray(v_ticks, dtype=float)[None, :, None]
        self.lattice(np.asarray(origin, dtype=float) + s * u + t * v, skip)

    def box(self, lo, hi, faces=ALL_FACES, steps=(None, None, None), inward=False):
        """Axis-aligned box: each face its own quad grid (cells ~steps per axis), normals out (or in)."""
        lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        axis_ticks = [ticks([lo[a], hi[a]], steps[a]) for a in range(3)]
        for face in faces:
            axis = "xyz".index(face[1])
            b, c = BOX_FACE_AXES[face][::-1] if inward else BOX_FACE_AXES[face]
            origin = np.zeros(3)
            origin[axis] = hi[axis] if face[0] == "+" else lo[axis]
            self.grid(origin, np.eye(3)[b], np.eye(3)[c], axis_ticks[b], axis_ticks[c])

    def prism(self, outline_xz, y0, y1, bottom=True):
        """Vertical (Y-up) extrusion of a simple polygon: ngon caps and one quad per side."""
        outline = np.asarray(outline_xz, dtype=float)
        if area_from_above(outline) < 0:
            outline = outline[::-1]
        lower = np.column_stack([outline[:, 0], np.full(len(outline), y0), outline[:, 1]])
        upper = lower + [0, y1 - y0, 0]
        self.polygon(upper)
        if bottom:
            self.polygon(lower[::-1])
        for k in range(len(outline)):
            n = (k + 1) % len(outline)
            self.polygon([lower[k], lower[n], upper[n], upper[k]])

    def lathe(self, profile, segments, center=(0, 0, 0), radial_scale=1.0):
        """Surface of revolution about +Y of (radius, height) points, shared vertices.

        Normals face outward when the profile climbs the outside; radius-0 end
        points become poles closed with triangle fans. radial_scale may be a
        (segments, len(profile)) array (ribs, bumps).
        """
        profile = np.asarray(profile, dtype=float)
        phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)[:, None]
        radius = profile[:, 0] * radial_scale * np.ones((segments, 1))
        height = np.broadcast_to(profile[:, 1], radius.shape)
        ring = np.stack([radius * np.cos(phi), height, -radius * np.sin(phi)], axis=-1) + center
        first = 1 if profile[0, 0] == 0 else 0
        last = len(profile) - 1 if profile[-1, 0] == 0 else len(profile)
        nv = last - first
        points = ring[:, first:last].reshape(-1, 3)
        faces = list(lattice_quads(segments, nv, wrap=True))
        i = np.arange(segments)
        i1 = (i + 1) % segments
        if first:
            points = np.vstack([points, np.add(center, [0, profile[0, 1], 0])])
            faces += [[len(points) - 1, a * nv, b * nv] for a, b in zip(i1, i)]
        if last < len(profile):
            points = np.vstack([points, np.add(center, [0, profile[-1, 1], 0])])
            faces += [[a * nv + nv - 1, b * nv + nv - 1, len(points) - 1] for a, b in zip(i, i1)]
        self.add(points, [len(f) for f in faces], np.concatenate(faces))
