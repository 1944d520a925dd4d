"""Generate the usdbake sample stages (.usda) that live next to this script.

    python samples/generate.py [--out DIR]

All geometry is polygonal UsdGeom.Mesh (quads where natural, a few ngons and a
concave polygon in building.usda) wound counter-clockwise seen from the side
the surface faces (USD's default rightHanded orientation). Smooth surfaces
share vertices; hard (90 degree) edges get their own vertices. Every mesh has
a UsdPreviewSurface material bound through MaterialBindingAPI, every stage has
UsdLux lights, explicit upAxis / metersPerUnit and /World as defaultPrim.
Output is deterministic: the only randomness uses fixed seeds.

Stages:
  cornell_box.usda      Y-up, metersPerUnit 0.01: the classic Cornell box data kept
                        verbatim (~556 x 549 x 559 units, so ~5.5 m), front open
                        towards -Z, a RectLight plus an emissive quad under the ceiling.
  window_room.usda      Z-up, metersPerUnit 1: 4 x 5 x 3 m room with one window,
                        ground plane outside, sun + sky.
  building.usda         Y-up, metersPerUnit 1: L-shaped two-storey building with
                        recessed windows, balconies, roof overhang (~700 triangles).
  city_block.usda       Z-up, metersPerUnit 1: 3 x 3 city blocks, streets, sidewalks
                        (~9,000 triangles).
  atrium.usda           Y-up, metersPerUnit 1: Sponza-like two-storey courtyard with
                        colonnades, arches, balustrade and hanging cloths (~50k triangles).
  instanced_props.usda  Y-up, metersPerUnit 1: a time-sampled PointInstancer (vase and
                        crate prototypes) and instanceable references to a class bench.

After writing, verify() re-opens every stage, prints a summary table and checks
the triangle budgets.
"""

import argparse
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

X, Y, Z = np.eye(3)
DECIMALS = 4  # points are rounded to 4 decimals to keep the ASCII files compact

# Tangent axes (b, c) of each box face, ordered so that e_b x e_c is the outward normal.
BOX_FACE_AXES = {"+x": (1, 2), "-x": (2, 1), "+y": (2, 0), "-y": (0, 2), "+z": (0, 1), "-z": (1, 0)}
ALL_FACES = tuple(BOX_FACE_AXES)


# --------------------------------------------------------------------------- geometry

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


# --------------------------------------------------------------------------- stage helpers

def new_stage(up_axis, meters_per_unit, doc):
    """In-memory stage: explicit upAxis / metersPerUnit, /World as defaultPrim, Looks and Lights scopes."""
    stage = Usd.Stage.CreateInMemory()
    stage.GetRootLayer().documentation = f"usdbake sample: {doc} (generated by samples/generate.py)"
    UsdGeom.SetStageUpAxis(stage, up_axis)
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    UsdGeom.Scope.Define(stage, "/World/Looks")
    UsdGeom.Scope.Define(stage, "/World/Lights")
    return stage


def save(stage, path):
    """Write the stage's root layer as ASCII .usda."""
    stage.GetRootLayer().Export(str(path))


def make_material(stage, name, color, roughness, emissive=None, metallic=None):
    """UsdPreviewSurface material /World/Looks/<name> with constant inputs."""
    path = f"/World/Looks/{name}"
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    if emissive is not None:
        shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    if metallic is not None:
        shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(metallic)
    surface = shader.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    material.CreateSurfaceOutput().ConnectToSource(surface)
    return material


def make_materials(stage, specs):
    """Materials from {name: (color, roughness, extra keyword args...)} as {name: material}."""
    return {name: make_material(stage, name, *spec[:2], **(spec[2] if len(spec) > 2 else {}))
            for name, spec in specs.items()}


def write_mesh(stage, path, builder, material, double_sided=False):
    """Define a polygonal UsdGeom.Mesh (points, topology, extent) and bind `material`."""
    points, counts, indices = builder.arrays()
    points = np.round(points, DECIMALS).astype(np.float32)
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices.astype(np.int32)))
    mesh.CreateExtentAttr([Gf.Vec3f(*points.min(axis=0).tolist()), Gf.Vec3f(*points.max(axis=0).tolist())])
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    if double_sided:
        mesh.CreateDoubleSidedAttr(True)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def add_sun(stage, rotate_xyz, intensity=50000.0, color=(1.0, 0.95, 0.86)):
    """DistantLight /World/Lights/Sun (shines along local -Z) tilted by rotate_xyz degrees.

    The fallback intensity 50000 with the 0.53 degree angle approximates sunlight.
    """
    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
    sun.CreateIntensityAttr(intensity)
    sun.CreateExposureAttr(0.0)
    sun.CreateColorAttr(Gf.Vec3f(*color))
    sun.CreateAngleAttr(0.53)
    sun.AddRotateXYZOp().Set(Gf.Vec3f(*rotate_xyz))
    return sun


def add_sky(stage, intensity=0.3, color=(0.55, 0.7, 1.0)):
    """Untextured DomeLight /World/Lights/Sky of a constant sky color."""
    sky = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    sky.CreateIntensityAttr(intensity)
    sky.CreateExposureAttr(0.0)
    sky.CreateColorAttr(Gf.Vec3f(*color))
    return sky


# --------------------------------------------------------------------------- cornell_box.usda

# Classic Cornell box data (Cornell Program of Computer Graphics), Y-up, open towards -Z.
CORNELL_WALLS = {
    "Floor": ("White", [(552.8, 0, 0), (0, 0, 0), (0, 0, 559.2), (549.6, 0, 559.2)]),
    "Ceiling": ("White", [(556, 548.8, 0), (556, 548.8, 559.2), (0, 548.8, 559.2), (0, 548.8, 0)]),
    "BackWall": ("White", [(549.6, 0, 559.2), (0, 0, 559.2), (0, 548.8, 559.2), (556, 548.8, 559.2)]),
    "RightWall": ("Green", [(0, 0, 559.2), (0, 0, 0), (0, 548.8, 0), (0, 548.8, 559.2)]),
    "LeftWall": ("Red", [(552.8, 0, 0), (549.6, 0, 559.2), (556, 548.8, 559.2), (556, 548.8, 0)]),
}
# Blocks: (x, z) outline of the top and height; the classic sides are its vertical extrusion.
CORNELL_BLOCKS = {
    "ShortBlock": ([(130, 65), (82, 225), (240, 272), (290, 114)], 165),
    "TallBlock": ([(423, 247), (265, 296), (314, 456), (472, 406)], 330),
}
CORNELL_LIGHT = (213, 343, 227, 332)  # x0, x1, z0, z1 of the 130 x 105 light
CORNELL_EMISSION = (17.0, 12.0, 4.0)


def build_cornell_box():
    """Cornell box: 5 walls (2x2 quads each), two rotated blocks, RectLight + emissive quad."""
    stage = new_stage(UsdGeom.Tokens.y, 0.01, "Cornell box, classic data in centimetres")
    looks = make_materials(stage, {
        "White": ((0.725, 0.71, 0.68), 0.9),
        "Red": ((0.63, 0.065, 0.05), 0.9),
        "Green": ((0.14, 0.45, 0.091), 0.9),
        "Light": ((0.78, 0.78, 0.78), 0.9, {"emissive": CORNELL_EMISSION}),
    })
    UsdGeom.Xform.Define(stage, "/World/CornellBox")
    for name, (look, corners) in CORNELL_WALLS.items():
        wall = MeshBuilder()
        wall.lattice(bilinear_patch(corners, 2, 2))  # corners wind so the walls face into the box
        write_mesh(stage, f"/World/CornellBox/{name}", wall, looks[look])
    for name, (outline, height) in CORNELL_BLOCKS.items():
        block = MeshBuilder()
        block.prism(outline, 0, height, bottom=False)  # resting on the floor, as in the classic data
        write_mesh(stage, f"/World/CornellBox/{name}", block, looks["White"])

    x0, x1, z0, z1 = CORNELL_LIGHT
    emitter = MeshBuilder()
    emitter.polygon([(x0, 548.6, z0), (x1, 548.6, z0), (x1, 548.6, z1), (x0, 548.6, z1)], facing=-Y)
    write_mesh(stage, "/World/CornellBox/LightQuad", emitter, looks["Light"])

    light = UsdLux.RectLight.Define(stage, "/World/Lights/CeilingLight")
    light.CreateWidthAttr(x1 - x0)
    light.CreateHeightAttr(z1 - z0)
    light.CreateIntensityAttr(max(CORNELL_EMISSION))  # same radiance as the emissive quad
    light.CreateExposureAttr(0.0)
    light.CreateColorAttr(Gf.Vec3f(*np.divide(CORNELL_EMISSION, max(CORNELL_EMISSION))))
    light.AddTranslateOp().Set(Gf.Vec3d((x0 + x1) / 2, 548.5, (z0 + z1) / 2))
    light.AddRotateXOp().Set(-90.0)  # local -Z (emission) -> world -Y; height runs along world Z
    return stage


# --------------------------------------------------------------------------- window_room.usda

ROOM_LO, ROOM_HI = (-2.0, -2.5, 0.0), (2.0, 2.5, 3.0)  # 4 x 5 x 3 m, Z-up
WINDOW_X, WINDOW_Z = (-0.8, 0.8), (0.9, 2.2)          # opening in the south wall (y = -2.5)


def build_window_room():
    """Closed room of inward-facing quads, one window in the south wall, ground, sun and sky."""
    stage = new_stage(UsdGeom.Tokens.z, 1.0, "room with one window")
    looks = make_materials(stage, {
        "Wall": ((0.8, 0.78, 0.74), 0.9),
        "Ceiling": ((0.9, 0.9, 0.9), 0.9),
        "WoodFloor": ((0.45, 0.3, 0.18), 0.6),
        "Cabinet": ((0.3, 0.4, 0.6), 0.5),
        "Ground": ((0.3, 0.35, 0.2), 1.0),
    })
    UsdGeom.Xform.Define(stage, "/World/Room")
    (x0, y0, z0), (x1, y1, z1) = ROOM_LO, ROOM_HI
    floor, ceiling, walls = MeshBuilder(), MeshBuilder(), MeshBuilder()
    floor.box(ROOM_LO, ROOM_HI, faces=("-z",), steps=(1, 1, None), inward=True)
    ceiling.box(ROOM_LO, ROOM_HI, faces=("+z",), steps=(2, 2.5, None), inward=True)
    walls.box(ROOM_LO, ROOM_HI, faces=("+x", "-x", "+y"), inward=True)
    # South wall facing +Y (into the room): 3 x 3 quads around the window, the middle cell left out.
    walls.grid((x0, y0, z0), Z, X, [0, WINDOW_Z[0], WINDOW_Z[1], z1 - z0],
               [0, WINDOW_X[0] - x0, WINDOW_X[1] - x0, x1 - x0], skip={(1, 1)})
    cabinet = MeshBuilder()
    cabinet.box((0.6, 1.4, 0.0), (1.8, 2.3, 0.9), faces=("+x", "-x", "+y", "-y", "+z"))
    ground = MeshBuilder()  # 20 x 20 m around the room, the room's footprint left out
    ground.grid((0, 0, 0), X, Y, [-10, x0, x1, 10], [-10, y0, y1, 10], skip={(1, 1)})

    for name, builder, look in (("Floor", floor, "WoodFloor"), ("Ceiling", ceiling, "Ceiling"),
                                ("Walls", walls, "Wall"), ("Cabinet", cabinet, "Cabinet")):
        write_mesh(stage, f"/World/Room/{name}", builder, looks[look])
    write_mesh(stage, "/World/Ground", ground, looks["Ground"])
    add_sun(stage, (55.0, 0.0, 20.0))  # 35 degrees above the horizon, shining north through the window
    add_sky(stage)
    return stage


# --------------------------------------------------------------------------- building.usda

BAY = 4.0                  # façade module along a wall (m)
STOREY = 3.2               # floor-to-floor height (m)
STOREYS = 2
WINDOW_SPAN = (1.2, 2.8)   # window inside a bay
WINDOW_SILL_HEAD = (0.9, 2.3)  # window inside a storey
RECESS = 0.25              # window recess depth (m)
ROOF = (6.4, 6.8)          # roof slab bottom and top
# L-shaped footprint (x, z), counter-clockwise seen from above; True: the wall after the corner has windows.
FOOTPRINT = [(-10, 10), (-2, 10), (-2, 2), (10, 2), (10, -6), (-10, -6)]
WINDOWED = [False, False, False, True, True, True]
ROOF_OUTLINE = [(-10.5, 10.5), (-1.5, 10.5), (-1.5, 2.5), (10.5, 2.5), (10.5, -6.5), (-10.5, -6.5)]
# Balcony: hexagon in façade coordinates (along the wall, out of the wall).
BALCONY = [(-1.6, -0.1), (1.6, -0.1), (1.6, 1.0), (1.2, 1.4), (-1.2, 1.4), (-1.6, 1.0)]


def opening_ticks(length, module, opening, count):
    """0, a0, b0, a1, b1, ..., length where (a_k, b_k) is the opening inside module k."""
    return [0.0, *(k * module + edge for k in range(count) for edge in opening), length]


def add_window_recess(walls, glass, corner, width, height):
    """Four reveals into the wall and a recessed pane for the opening at corner + width x height."""
    depth = -RECESS * unit(np.cross(width, height))
    front = [corner, corner + width, corner + width + height, corner + height]
    back = [p + depth for p in front]
    glass.polygon(back)
    for k in range(4):  # edge x depth points into the opening for a counter-clockwise outline
        walls.polygon([front[k], front[(k + 1) % 4], back[(k + 1) % 4], back[k]])


def add_facade(walls, glass, start, end, windowed):
    """Wall between two footprint corners as a quad grid, windowed walls with recessed windows."""
    start = np.array([start[0], 0.0, start[1]])
    end = np.array([end[0], 0.0, end[1]])
    length = np.linalg.norm(end - start)
    along = (end - start) / length  # along x Y is the outward normal
    bays = int(round(length / BAY))
    if not windowed:
        walls.grid(start, along, Y, np.linspace(0, length, bays + 1), np.arange(STOREYS + 1) * STOREY)
        return
    u_ticks = opening_ticks(length, BAY, WINDOW_SPAN, bays)
    v_ticks = opening_ticks(STOREYS * STOREY, STOREY, WINDOW_SILL_HEAD, STOREYS)
    openings = sorted((2 * i + 1, 2 * j + 1) for i in range(bays) for j in range(STOREYS))
    walls.grid(start, along, Y, u_ticks, v_ticks, skip=openings)
    for i, j in openings:
        corner = start + along * u_ticks[i] + Y * v_ticks[j]
        add_window_recess(walls, glass, corner, along * (u_ticks[i + 1] - u_ticks[i]),
                          Y * (v_ticks[j + 1] - v_ticks[j]))


def add_balcony(slabs, rails, center_xz, along_xz, out_xz, floor_y):
    """Hexagonal slab sticking out of a wall at floor_y with a front parapet."""
    center, along, out = (np.asarray(v, dtype=float) for v in (center_xz, along_xz, out_xz))
    outline = [center + a * along + b * out for a, b in BALCONY]
    slabs.prism(outline, floor_y - 0.2, floor_y)
    corners = np.array([center + a * along + b * out for a, b in ((-1.2, 1.3), (1.2, 1.4))])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    rails.box((lo[0], floor_y, lo[1]), (hi[0], floor_y + 1.0, hi[1]), faces=("+x", "-x", "+y", "+z", "-z"))


def build_building():
    """L-shaped building: gridded façades, window recesses, balconies, roof slab, tank, ground."""
    stage = new_stage(UsdGeom.Tokens.y, 1.0, "L-shaped building")
    looks = make_materials(stage, {
        "Plaster": ((0.8, 0.76, 0.7), 0.85),
        "Glass": ((0.1, 0.14, 0.18), 0.05),
        "Concrete": ((0.55, 0.55, 0.53), 0.8),
        "Metal": ((0.6, 0.62, 0.65), 0.35, {"metallic": 0.8}),
        "Grass": ((0.25, 0.4, 0.15), 1.0),
    })
    UsdGeom.Xform.Define(stage, "/World/Building")
    walls, glass = MeshBuilder(), MeshBuilder()
    for k, windowed in enumerate(WINDOWED):
        add_facade(walls, glass, FOOTPRINT[k], FOOTPRINT[(k + 1) % len(FOOTPRINT)], windowed)

    roof = MeshBuilder()
    roof.prism(ROOF_OUTLINE, *ROOF)  # concave L-shaped caps, 0.5 m overhang
    roof.box((-11.5, 2.6, -1.5), (-10.0, 2.8, 1.5), faces=("-x", "+y", "-y", "+z", "-z"))  # entrance canopy
    slabs, metal = MeshBuilder(), MeshBuilder()
    for x in (4.0, -4.0):  # upper-storey balconies on the south façade (z = -6)
        add_balcony(slabs, metal, (x, -6.0), (-1, 0), (0, -1), STOREY)
    octagon = [(-6 + 1.2 * np.cos(a), 6 + 1.2 * np.sin(a)) for a in np.arange(8) * np.pi / 4]
    metal.prism(octagon, ROOF[1], ROOF[1] + 1.6, bottom=False)  # water tank
    ground = MeshBuilder()
    ground.grid((0, 0, 0), Z, X, np.linspace(-30, 30, 9), np.linspace(-30, 30, 9))

    for name, builder, look in (("Walls", walls, "Plaster"), ("Windows", glass, "Glass"), ("Roof", roof, "Concrete"),
                                ("Balconies", slabs, "Concrete"), ("Metalwork", metal, "Metal")):
        write_mesh(stage, f"/World/Building/{name}", builder, looks[look])
    write_mesh(stage, "/World/Ground", ground, looks["Grass"])
    add_sun(stage, (-50.0, 35.0, 0.0))  # 50 degrees up
    add_sky(stage)
    return stage


# --------------------------------------------------------------------------- city_block.usda

BLOCK_GRID = 3          # blocks per side
BLOCK_SIZE = 40.0       # sidewalk slab per block (m)
BLOCK_PITCH = 52.0      # block size + 12 m street
CURB = 0.15             # sidewalk height
LOTS = ((-17.0, -2.0), (2.0, 17.0))  # 2 x 2 building lots per block (block-local x or y range)
FACADE_STEPS = (5.0, 5.0, 3.5)        # façade quads: ~5 m bays, 3.5 m floors
FACADE_LOOKS = ("Concrete", "Brick", "Sandstone", "BlueGlass")


def block_centers():
    """Block centre coordinate along one axis."""
    return (np.arange(BLOCK_GRID) - (BLOCK_GRID - 1) / 2) * BLOCK_PITCH


def add_tower(building, units, rng, lo_xy, hi_xy):
    """Box building on a lot (optionally with a setback tier) and 1-2 rooftop units."""
    lo, hi = np.array([*lo_xy, CURB]), np.array([*hi_xy, CURB + rng.uniform(8, 40)])
    building.box(lo, hi, faces=("+x", "-x", "+y", "-y", "+z"), steps=FACADE_STEPS)
    if rng.random() < 0.4:  # setback tier
        inset = rng.uniform(2.0, 3.5)
        lo, hi = lo + [inset, inset, 0], hi + [-inset, -inset, 0]
        lo[2], hi[2] = hi[2], hi[2] + rng.uniform(5, 12)
        building.box(lo, hi, faces=("+x", "-x", "+y", "-y", "+z"), steps=FACADE_STEPS)
    for _ in range(rng.integers(1, 3)):
        size = rng.uniform(1.5, 3.5, 2)
        corner = rng.uniform(lo[:2] + 0.5, hi[:2] - 0.5 - size)
        units.box([*corner, hi[2]], [*(corner + size), hi[2] + rng.uniform(1.2, 3.0)],
                  faces=("+x", "-x", "+y", "-y", "+z"))


def build_city_block():
    """3 x 3 blocks of towers on raised sidewalks, tessellated streets, sun and sky."""
    stage = new_stage(UsdGeom.Tokens.z, 1.0, "city blocks")
    looks = make_materials(stage, {
        "Concrete": ((0.62, 0.6, 0.56), 0.8),
        "Brick": ((0.55, 0.3, 0.22), 0.85),
        "Sandstone": ((0.76, 0.68, 0.52), 0.8),
        "BlueGlass": ((0.35, 0.42, 0.5), 0.2),
        "RoofUnits": ((0.5, 0.52, 0.55), 0.4, {"metallic": 0.6}),
        "Sidewalk": ((0.7, 0.69, 0.66), 0.9),
        "Asphalt": ((0.12, 0.12, 0.13), 0.95),
    })
    UsdGeom.Xform.Define(stage, "/World/City")
    rng = np.random.default_rng(2024)  # fixed seed: identical output on every run
    centers = block_centers()
    for r, cy in enumerate(centers):
        for c, cx in enumerate(centers):
            block = UsdGeom.Xform.Define(stage, f"/World/City/Block_{r}_{c}")
            block.AddTranslateOp().Set(Gf.Vec3d(cx, cy, 0))
            path = block.GetPath().pathString
            sidewalk = MeshBuilder()
            half = BLOCK_SIZE / 2
            sidewalk.box((-half, -half, 0), (half, half, CURB), faces=("+x", "-x", "+y", "-y", "+z"),
                         steps=(8.0, 8.0, None))
            write_mesh(stage, f"{path}/Sidewalk", sidewalk, looks["Sidewalk"])
            units = MeshBuilder()
            lots = [(xs, ys) for ys in LOTS for xs in LOTS]
            for k, (xs, ys) in enumerate(lots):
                building = MeshBuilder()
                inset = rng.uniform(0, 1.5, 2)
                add_tower(building, units, rng, (xs[0] + inset[0], ys[0] + inset[1]),
                          (xs[1] - inset[0], ys[1] - inset[1]))
                write_mesh(stage, f"{path}/Building_{k}", building, looks[FACADE_LOOKS[rng.integers(4)]])
            write_mesh(stage, f"{path}/RoofUnits", units, looks["RoofUnits"])

    edges = np.sort(np.concatenate([centers - BLOCK_SIZE / 2, centers + BLOCK_SIZE / 2]))
    extent = edges[-1] + (BLOCK_PITCH - BLOCK_SIZE)
    road_ticks = ticks([-extent, *edges, extent], 8.0)
    mids = (road_ticks[:-1] + road_ticks[1:]) / 2
    in_block = np.abs(mids[:, None] - centers[None, :]).min(axis=1) < BLOCK_SIZE / 2
    streets = MeshBuilder()
    streets.grid((0, 0, 0), X, Y, road_ticks, road_ticks,
                 skip=[(i, j) for i in np.flatnonzero(in_block) for j in np.flatnonzero(in_block)])
    write_mesh(stage, "/World/City/Streets", streets, looks["Asphalt"])
    add_sun(stage, (40.0, 0.0, 30.0))  # 50 degrees up
    add_sky(stage)
    return stage


# --------------------------------------------------------------------------- atrium.usda

COURT = (15.0, 6.0)         # colonnade lines at x = +-15 and z = +-6
OUTER = (19.0, 10.0)        # outer walls at x = +-19 and z = +-10
BAY_SPAN = 3.0              # column spacing
SPRING = 4.0                # column height = arch springing line
ARCH_RADIUS = 1.1           # clear half span between abaci
ARCH_DEPTH = 0.3            # half thickness of the arcade wall
ARCH_SEGMENTS = 16          # multiple of 4 so the spandrel corners (45, 135 degrees) are vertices
LEVEL_HEIGHT = 6.0          # storey height; the slab fills SPRING + BAY_SPAN/2 .. LEVEL_HEIGHT
HOLE = (14.55, 5.55)        # courtyard opening of the gallery / roof slabs
COLUMN_SEGMENTS = 24
# Column lathe profile (radius, height): torus base, slightly tapering shaft, echinus under the abacus.
COLUMN_PROFILE = [(0.36, 0.25), (0.385, 0.3), (0.37, 0.36), (0.32, 0.41), (0.3, 0.45), (0.295, 1.6),
                  (0.27, 3.45), (0.3, 3.58), (0.35, 3.68), (0.38, 3.76)]
BALUSTER_PROFILE = [(0.06, 0.15), (0.085, 0.32), (0.05, 0.55), (0.04, 0.75), (0.06, 0.85)]
CLOTH_LOOKS = ("RedCloth", "GreenCloth", "BlueCloth")


def colonnade_sides():
    """(line centre, rows (along s, up, inward w), half length, owns its end columns) per side."""
    sides = []
    for center, inward, half, owns_corners in (((0, 0, COURT[1]), -Z, COURT[0], True),
                                               ((0, 0, -COURT[1]), Z, COURT[0], True),
                                               ((COURT[0], 0, 0), -X, COURT[1], False),
                                               ((-COURT[0], 0, 0), X, COURT[1], False)):
        axes = np.array([np.cross(Y, inward), Y, inward])  # s x up = w, a proper rotation
        sides.append((np.array(center, dtype=float), axes, half, owns_corners))
    return sides


def span_centers(half):
    """Along-line coordinates of the bay centres of a colonnade side."""
    return np.arange(-half + BAY_SPAN / 2, half, BAY_SPAN)


def column_positions():
    """World (x, z) of every column of one storey, corners once."""
    positions = []
    for center, axes, half, owns_corners in colonnade_sides():
        s_values = np.arange(-half, half + 1e-6, BAY_SPAN)
        for s in s_values if owns_corners else s_values[1:-1]:
            position = center + axes[0] * s
            positions.append((position[0], position[2]))
    return positions


def column():
    """One column at the origin: square plinth, turned base/shaft/echinus, square abacus."""
    builder = MeshBuilder()
    builder.box((-0.4, 0, -0.4), (0.4, 0.25, 0.4), faces=("+x", "-x", "+y", "+z", "-z"))
    builder.lathe(COLUMN_PROFILE, COLUMN_SEGMENTS)
    builder.box((-0.4, 3.76, -0.4), (0.4, SPRING, 0.4))
    return builder


def arch_bay():
    """One arcade bay in local (s, y, w): both spandrel faces and the semicircular soffit."""
    theta = np.linspace(0, np.pi, ARCH_SEGMENTS + 1)
    direction = np.column_stack([np.cos(theta), np.sin(theta)])
    intrados = ARCH_RADIUS * direction
    outline = direction * (BAY_SPAN / 2 / np.abs(direction).max(axis=1))[:, None]  # on the bay's square

    def at(points, w):
        """(s, y) outline points lifted to the spring line at depth w."""
        return np.column_stack([points[:, 0], SPRING + points[:, 1], np.full(len(points), w)])

    builder = MeshBuilder()
    builder.lattice(np.stack([at(outline, ARCH_DEPTH), at(intrados, ARCH_DEPTH)], axis=1))     # faces +w
    builder.lattice(np.stack([at(intrados, -ARCH_DEPTH), at(outline, -ARCH_DEPTH)], axis=1))   # faces -w
    builder.lattice(np.stack([at(intrados, ARCH_DEPTH), at(intrados, -ARCH_DEPTH)], axis=1))   # soffit
    return builder


def balustrade_bay():
    """Rails and turned balusters between two gallery columns in local (s, y, w)."""
    builder = MeshBuilder()
    builder.box((-1.1, 0, -0.15), (1.1, 0.15, 0.15), faces=("+x", "-x", "+y", "+z", "-z"))
    builder.box((-1.25, 0.85, -0.17), (1.25, 1.0, 0.17))
    for s in np.arange(-0.8, 0.81, 0.4):
        builder.lathe(BALUSTER_PROFILE, 8, center=(s, 0, 0))
    return builder


def ring_slab(y0, y1):
    """Slab between the outer walls and the courtyard opening: top, soffit and inner edge faces."""
    x_ticks = ticks([-OUTER[0], -HOLE[0], HOLE[0], OUTER[0]], 1.1)
    z_ticks = ticks([-OUTER[1], -HOLE[1], HOLE[1], OUTER[1]], 1.1)
    x_mid, z_mid = (x_ticks[:-1] + x_ticks[1:]) / 2, (z_ticks[:-1] + z_ticks[1:]) / 2
    hole_x, hole_z = np.flatnonzero(np.abs(x_mid) < HOLE[0]), np.flatnonzero(np.abs(z_mid) < HOLE[1])
    builder = MeshBuilder()
    builder.grid((0, y1, 0), Z, X, z_ticks, x_ticks, skip=[(i, j) for i in hole_z for j in hole_x])
    builder.grid((0, y0, 0), X, Z, x_ticks, z_ticks, skip=[(i, j) for i in hole_x for j in hole_z])
    builder.box((-HOLE[0], y0, -HOLE[1]), (HOLE[0], y1, HOLE[1]), faces=("+x", "-x", "+z", "-z"),
                steps=(1.1, None, 1.1), inward=True)
    return builder


def cloth(width=2.2, top=5.45, bottom=1.7):
    """Hanging cloth in local (s, y, w): wavy folds, bottom swinging towards the courtyard (+w)."""
    s = np.linspace(-width / 2, width / 2, 13)[:, None]
    y = np.linspace(bottom, top, 17)[None, :]
    drop = (top - y) / (top - bottom)  # 0 at the top edge, 1 at the hem
    w = 0.45 + 0.07 * np.sin(6 * np.pi * s / width) * (0.4 + 0.6 * drop) + 0.25 * drop ** 2
    builder = MeshBuilder()
    builder.lattice(np.stack(np.broadcast_arrays(s, y, w), axis=-1))  # s x y = +w: faces the courtyard
    return builder


def build_level(stage, path, looks, height, with_balustrade):
    """One storey under an Xform at `height`: columns (own transforms), arcade, slab above."""
    level = UsdGeom.Xform.Define(stage, path)
    level.AddTranslateOp().Set(Gf.Vec3d(0, height, 0))
    UsdGeom.Xform.Define(stage, f"{path}/Columns")
    shaft = column()
    for k, (x, z) in enumerate(column_positions()):
        mesh = write_mesh(stage, f"{path}/Columns/Column_{k:02d}", shaft, looks["Stone"])
        mesh.AddTranslateOp().Set(Gf.Vec3d(x, 0, z))

    arches, bay = MeshBuilder(), arch_bay()
    for center, axes, half, _ in colonnade_sides():
        for s in span_centers(half):
            arches.extend(bay, axes, center + axes[0] * s)
    for sx in (-1, 1):  # close the arcade where two sides meet
        for sz in (-1, 1):
            corner = np.array([sx * COURT[0], SPRING, sz * COURT[1]])
            arches.box(corner - [ARCH_DEPTH, 0, ARCH_DEPTH], corner + [ARCH_DEPTH, BAY_SPAN / 2, ARCH_DEPTH],
                       faces=("+x", "-x", "+z", "-z"))
    write_mesh(stage, f"{path}/Arcade", arches, looks["Stone"])
    write_mesh(stage, f"{path}/Slab", ring_slab(SPRING + BAY_SPAN / 2, LEVEL_HEIGHT), looks["Plaster"])
    if with_balustrade:
        balustrade, rail = MeshBuilder(), balustrade_bay()
        for center, axes, half, _ in colonnade_sides():
            for s in span_centers(half):
                balustrade.extend(rail, axes, center + axes[0] * s)
        write_mesh(stage, f"{path}/Balustrade", balustrade, looks["Stone"])


def build_atrium():
    """Sponza-like courtyard: paved floor, walls, two colonnaded storeys, roof ring, cloths."""
    stage = new_stage(UsdGeom.Tokens.y, 1.0, "Sponza-like atrium")
    looks = make_materials(stage, {
        "Stone": ((0.72, 0.66, 0.56), 0.7),
        "Plaster": ((0.78, 0.72, 0.62), 0.85),
        "Paving": ((0.55, 0.5, 0.45), 0.8),
        "RedCloth": ((0.6, 0.05, 0.05), 0.9),
        "GreenCloth": ((0.08, 0.4, 0.1), 0.9),
        "BlueCloth": ((0.08, 0.12, 0.5), 0.9),
    })
    UsdGeom.Xform.Define(stage, "/World/Atrium")
    roof_top = 2 * LEVEL_HEIGHT
    floor, walls, parapet = MeshBuilder(), MeshBuilder(), MeshBuilder()
    floor.grid((0, 0, 0), Z, X, ticks([-OUTER[1], OUTER[1]], 1.0), ticks([-OUTER[0], OUTER[0]], 1.0))
    walls.box((-OUTER[0], 0, -OUTER[1]), (OUTER[0], roof_top, OUTER[1]), faces=("+x", "-x", "+z", "-z"),
              steps=(2.0, 1.5, 2.0), inward=True)
    for sz in (-1, 1):  # parapet along the courtyard edge of the roof
        z0, z1 = sorted((sz * HOLE[1], sz * (HOLE[1] + 0.3)))
        parapet.box((-HOLE[0] - 0.3, roof_top, z0), (HOLE[0] + 0.3, roof_top + 0.6, z1),
                    faces=("+x", "-x", "+y", "+z", "-z"), steps=(1.5, None, None))
    for sx in (-1, 1):
        x0, x1 = sorted((sx * HOLE[0], sx * (HOLE[0] + 0.3)))
        parapet.box((x0, roof_top, -HOLE[1]), (x1, roof_top + 0.6, HOLE[1]),
                    faces=("+x", "-x", "+y"), steps=(None, None, 1.5))
    write_mesh(stage, "/World/Atrium/Floor", floor, looks["Paving"])
    write_mesh(stage, "/World/Atrium/Walls", walls, looks["Plaster"])
    write_mesh(stage, "/World/Atrium/Parapet", parapet, looks["Stone"])
    build_level(stage, "/World/Atrium/Level_0", looks, 0.0, with_balustrade=False)
    build_level(stage, "/World/Atrium/Level_1", looks, LEVEL_HEIGHT, with_balustrade=True)

    UsdGeom.Xform.Define(stage, "/World/Atrium/Cloths")
    drape, k = cloth(), 0
    for center, axes, half, owns_corners in colonnade_sides():
        if not owns_corners:
            continue
        for s in span_centers(half)[1::2]:  # every other ground-floor bay of the long sides
            builder = MeshBuilder()
            builder.extend(drape, axes, center + axes[0] * s)
            write_mesh(stage, f"/World/Atrium/Cloths/Cloth_{k:02d}", builder,
                       looks[CLOTH_LOOKS[k % 3]], double_sided=True)
            k += 1

    add_sun(stage, (-58.0, 30.0, 0.0))  # 58 degrees up, so part of the courtyard floor is sunlit
    add_sky(stage)
    for k, position in enumerate(((-9.0, 10.5, 8.2), (9.0, 10.5, -8.2))):  # upper gallery lamps
        lamp = UsdLux.SphereLight.Define(stage, f"/World/Lights/GalleryLamp_{k}")
        lamp.CreateRadiusAttr(0.12)
        lamp.CreateIntensityAttr(15.0)
        lamp.CreateExposureAttr(3.0)
        lamp.CreateColorAttr(Gf.Vec3f(1.0, 0.8, 0.6))
        lamp.AddTranslateOp().Set(Gf.Vec3d(*position))
    return stage


# --------------------------------------------------------------------------- instanced_props.usda

VASES, CRATES = 60, 20
FRAMES = (1, 2, 3)
BENCH_X = (-9.0, -3.0, 3.0, 9.0)


def vase():
    """Ribbed vase (closed lathe surface with a hollow neck), ~6k triangles."""
    t = np.linspace(0.02, 1.0, 38)
    height = 0.85 * t
    radius = (0.09 + 0.16 * np.exp(-((t - 0.35) / 0.25) ** 2) + 0.02 * t
              + 0.03 * np.exp(-((t - 1.0) / 0.06) ** 2))
    outer = list(zip(radius, height))
    lip = radius[-1]
    profile = [(0.0, 0.0), (0.1, 0.0), *outer, (lip - 0.005, 0.86), (lip - 0.03, 0.855),
               (0.085, 0.8), (0.075, 0.75), (0.0, 0.73)]
    segments = 72
    ribs = np.zeros(len(profile))
    ribs[2:2 + len(outer)] = np.sin(np.pi * t)  # ribs fade out at the foot and the lip
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)[:, None]
    builder = MeshBuilder()
    builder.lathe(profile, segments, radial_scale=1 + 0.035 * np.cos(18 * phi) * ribs)
    return builder


def crate():
    """0.7 m crate resting on y = 0 (no hidden bottom face)."""
    builder = MeshBuilder()
    builder.box((-0.35, 0, -0.35), (0.35, 0.7, 0.35), faces=("+x", "-x", "+y", "+z", "-z"))
    return builder


def bench_parts():
    """Bench (along X, facing -Z) as (slats, frame) builders."""
    slats, frame = MeshBuilder(), MeshBuilder()
    for z0, z1 in ((-0.25, -0.1), (-0.075, 0.075), (0.1, 0.25)):
        slats.box((-0.9, 0.42, z0), (0.9, 0.46, z1))
    for y0, y1 in ((0.6, 0.72), (0.8, 0.92)):
        slats.box((-0.9, y0, 0.26), (0.9, y1, 0.3))
    for x0 in (-0.8, 0.74):
        frame.box((x0, 0, -0.22), (x0 + 0.06, 0.42, 0.22), faces=("+x", "-x", "+y", "+z", "-z"))
        frame.box((x0, 0.42, 0.3), (x0 + 0.06, 0.95, 0.34))
    return slats, frame


def quat_y(angle):
    """Gf.Quath rotating `angle` radians about +Y."""
    return Gf.Quath(float(np.cos(angle / 2)), 0.0, float(np.sin(angle / 2)), 0.0)


def add_scatter(stage, looks):
    """PointInstancer with vase + crate prototypes, at the default time and time-sampled frames."""
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    UsdGeom.Scope.Define(stage, "/World/Scatter/Prototypes")
    vase_mesh = write_mesh(stage, "/World/Scatter/Prototypes/Vase", vase(), looks["Terracotta"])
    crate_mesh = write_mesh(stage, "/World/Scatter/Prototypes/Crate", crate(), looks["Wood"])
    instancer.CreatePrototypesRel().SetTargets([vase_mesh.GetPath(), crate_mesh.GetPath()])

    rng = np.random.default_rng(7)  # fixed seed: identical output on every run
    gx, gz = np.meshgrid(np.linspace(-13.5, 13.5, 10), np.linspace(-13.5, 9.0, 8))
    base = np.column_stack([gx.ravel(), np.zeros(gx.size), gz.ravel()])
    base[:, [0, 2]] += rng.uniform(-0.6, 0.6, (len(base), 2))
    proto = rng.permutation(np.repeat([0, 1], [VASES, CRATES]))
    angle = rng.uniform(0, 2 * np.pi, len(base))
    scale = rng.uniform(0.8, 1.3, len(base))
    slide = rng.normal(size=(len(base), 3)) * [1, 0, 1]
    slide *= 0.15 / np.linalg.norm(slide, axis=1, keepdims=True)  # 15 cm per frame

    instancer.CreateProtoIndicesAttr(Vt.IntArray(proto.tolist()))
    instancer.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(float(s), float(s), float(s)) for s in scale]))
    positions = instancer.CreatePositionsAttr()
    orientations = instancer.CreateOrientationsAttr()
    for time, offset in [(Usd.TimeCode.Default(), 0)] + [(Usd.TimeCode(f), f - FRAMES[0]) for f in FRAMES]:
        points = np.round(base + offset * slide, DECIMALS).astype(np.float32)
        positions.Set(Vt.Vec3fArray.FromNumpy(points), time)
        orientations.Set(Vt.QuathArray([quat_y(a + offset * np.radians(4)) for a in angle]), time)


def add_benches(stage, looks):
    """Bench defined once as a class, referenced by four instanceable prims."""
    UsdGeom.Scope.Define(stage, "/World/Library")
    bench = stage.CreateClassPrim("/World/Library/Bench")
    bench.SetTypeName("Xform")
    slats, frame = bench_parts()
    write_mesh(stage, "/World/Library/Bench/Slats", slats, looks["Wood"])
    write_mesh(stage, "/World/Library/Bench/Frame", frame, looks["Iron"])
    UsdGeom.Xform.Define(stage, "/World/Benches")
    for k, x in enumerate(BENCH_X):
        instance = UsdGeom.Xform.Define(stage, f"/World/Benches/Bench_{k}")
        instance.GetPrim().GetReferences().AddInternalReference(bench.GetPath())
        instance.GetPrim().SetInstanceable(True)
        instance.AddTranslateOp().Set(Gf.Vec3d(x, 0, 12.5))


def build_instanced_props():
    """Floor, PointInstancer scatter (static + time-sampled) and instanceable benches."""
    stage = new_stage(UsdGeom.Tokens.y, 1.0, "instancing")
    stage.SetStartTimeCode(FRAMES[0])
    stage.SetEndTimeCode(FRAMES[-1])
    stage.SetTimeCodesPerSecond(24)
    looks = make_materials(stage, {
        "Floor": ((0.6, 0.6, 0.58), 0.8),
        "Terracotta": ((0.62, 0.3, 0.18), 0.7),
        "Wood": ((0.55, 0.38, 0.2), 0.75),
        "Iron": ((0.15, 0.15, 0.16), 0.5, {"metallic": 0.9}),
    })
    floor = MeshBuilder()
    floor.grid((0, 0, 0), Z, X, np.linspace(-15, 15, 16), np.linspace(-15, 15, 16))
    write_mesh(stage, "/World/Floor", floor, looks["Floor"])
    add_scatter(stage, looks)
    add_benches(stage, looks)
    add_sun(stage, (-50.0, 35.0, 0.0))
    add_sky(stage)
    return stage


# --------------------------------------------------------------------------- verification

STAGES = {
    "cornell_box.usda": build_cornell_box,
    "window_room.usda": build_window_room,
    "building.usda": build_building,
    "city_block.usda": build_city_block,
    "atrium.usda": build_atrium,
    "instanced_props.usda": build_instanced_props,
}
# Triangle budget per stage (meshes, PointInstancer prototypes counted once).
TRIANGLES = {
    "cornell_box.usda": (40, 120),
    "window_room.usda": (60, 140),
    "building.usda": (600, 800),
    "city_block.usda": (8000, 10000),
    "atrium.usda": (20000, 60000),
    "instanced_props.usda": (5000, 20000),
}


def is_concave(points):
    """True if a planar polygon has a reflex corner."""
    normal = newell_normal(points)
    edges = np.roll(points, -1, axis=0) - points
    turns = np.cross(edges, np.roll(edges, -1, axis=0)) @ normal
    return bool((turns < -1e-9).any())


def mesh_stats(prim):
    """(polygons, triangles, ngons, concave polygons) of one mesh prim."""
    mesh = UsdGeom.Mesh(prim)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    points = np.asarray(mesh.GetPointsAttr().Get(), dtype=float)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    concave = sum(is_concave(points[indices[s:s + n]]) for s, n in zip(starts, counts) if n > 4)
    if not UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]:
        raise AssertionError(f"{prim.GetPath()} has no bound material")
    return len(counts), int((counts - 2).sum()), int((counts > 4).sum()), concave


def stage_stats(path):
    """Summary numbers of one stage; PointInstancer prototypes are counted once, instances apart."""
    stage = Usd.Stage.Open(str(path))
    for key in ("upAxis", "metersPerUnit"):
        assert stage.HasAuthoredMetadata(key), f"{path.name}: {key} not authored"
    stats = dict(up_axis=stage.GetMetadata("upAxis"), meters_per_unit=stage.GetMetadata("metersPerUnit"),
                 default_prim=stage.GetDefaultPrim().GetPath().pathString, meshes=0, polygons=0, triangles=0,
                 ngons=0, concave=0, lights=0, instanced=0, largest_proto=(0, 0))

    def add_mesh(prim):
        """Add one mesh to the totals and return its triangle count."""
        polygons, triangles, ngons, concave = mesh_stats(prim)
        for key, value in zip(("meshes", "polygons", "triangles", "ngons", "concave"),
                              (1, polygons, triangles, ngons, concave)):
            stats[key] += value
        return triangles

    iterator = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()))
    for prim in iterator:
        if prim.IsA(UsdGeom.PointInstancer):
            iterator.PruneChildren()
            instancer = UsdGeom.PointInstancer(prim)
            proto_indices = np.asarray(instancer.GetProtoIndicesAttr().Get())
            for k, target in enumerate(instancer.GetPrototypesRel().GetTargets()):
                triangles = sum(add_mesh(p) for p in Usd.PrimRange(stage.GetPrimAtPath(target))
                                if p.IsA(UsdGeom.Mesh))
                copies = int((proto_indices == k).sum())
                stats["instanced"] += triangles * copies
                stats["largest_proto"] = max(stats["largest_proto"], (triangles, copies))
        elif prim.IsA(UsdGeom.Mesh):
            add_mesh(prim)
        stats["lights"] += prim.HasAPI(UsdLux.LightAPI)
    return stats


def verify(folder):
    """Re-open every stage, print a summary table and check metadata and triangle budgets."""
    header = (f"{'file':22} {'upAxis':>6} {'m/unit':>6} {'meshes':>6} {'polygons':>8} {'triangles':>9} "
              f"{'instanced':>9} {'ngons':>5} {'concave':>7} {'lights':>6} {'size':>8}")
    print(header)
    print("-" * len(header))
    stats = {}
    for name in STAGES:
        path = Path(folder) / name
        s = stats[name] = stage_stats(path)
        print(f"{name:22} {s['up_axis']:>6} {s['meters_per_unit']:>6} {s['meshes']:>6} {s['polygons']:>8} "
              f"{s['triangles']:>9} {s['instanced']:>9} {s['ngons']:>5} {s['concave']:>7} {s['lights']:>6} "
              f"{path.stat().st_size / 1e6:>6.2f}MB")
        low, high = TRIANGLES[name]
        assert low <= s["triangles"] <= high, f"{name}: {s['triangles']} triangles, expected {low}..{high}"
        assert s["default_prim"] == "/World" and s["lights"] >= 1 and s["meshes"] >= 1, name
    assert stats["building.usda"]["concave"] >= 1, "building.usda needs a concave polygon"
    triangles, copies = stats["instanced_props.usda"]["largest_proto"]
    assert triangles >= 5000 and copies == VASES, "the vase prototype needs >= 5000 triangles and 60 copies"


def main():
    """Write every stage to --out (default: this script's folder), then verify them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    out = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    for name, build in STAGES.items():
        save(build(), out / name)
    verify(out)


if __name__ == "__main__":
    main()
