"""atrium.usda: a Sponza-like two-storey courtyard (~50k triangles).

Y-up, metersPerUnit 1: paved floor, inward-facing outer walls, two storeys of colonnades with
turned columns and semicircular arches, a balustrade on the upper gallery, a roof ring with a
parapet, double-sided hanging cloths, sun, sky and two gallery lamps.
"""

import numpy as np
from pxr import Gf, UsdGeom, UsdLux

from mesh_builder import X, Y, Z, MeshBuilder, faces_except, ticks
from stage_authoring import add_daylight, new_stage, set_emission, write_mesh

FILE = "atrium.usda"
TRIANGLES = (20000, 60000)  # triangle budget checked after writing

MATERIALS = {
    "Stone": ((0.72, 0.66, 0.56), 0.7),
    "Plaster": ((0.78, 0.72, 0.62), 0.85),
    "Paving": ((0.55, 0.5, 0.45), 0.8),
    "RedCloth": ((0.6, 0.05, 0.05), 0.9),
    "GreenCloth": ((0.08, 0.4, 0.1), 0.9),
    "BlueCloth": ((0.08, 0.12, 0.5), 0.9),
}
"""UsdPreviewSurface looks: {name: (diffuse color, roughness, extra inputs)}."""

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
SIDES = faces_except("+y", "-y")  # walls and the arcade's corner piers: vertical faces only


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
    builder.box((-0.4, 0, -0.4), (0.4, 0.25, 0.4), faces=faces_except("-y"))
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
    builder.box((-1.1, 0, -0.15), (1.1, 0.15, 0.15), faces=faces_except("-y"))
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
    builder.box((-HOLE[0], y0, -HOLE[1]), (HOLE[0], y1, HOLE[1]), faces=SIDES,
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


def along_colonnades(bay):
    """`bay` (local (s, y, w)) repeated at every bay of the four colonnade sides."""
    builder = MeshBuilder()
    for center, axes, half, _ in colonnade_sides():
        for s in span_centers(half):
            builder.extend(bay, axes, center + axes[0] * s)
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

    arches = along_colonnades(arch_bay())
    for sx in (-1, 1):  # close the arcade where two sides meet
        for sz in (-1, 1):
            corner = np.array([sx * COURT[0], SPRING, sz * COURT[1]])
            arches.box(corner - [ARCH_DEPTH, 0, ARCH_DEPTH], corner + [ARCH_DEPTH, BAY_SPAN / 2, ARCH_DEPTH],
                       faces=SIDES)
    write_mesh(stage, f"{path}/Arcade", arches, looks["Stone"])
    write_mesh(stage, f"{path}/Slab", ring_slab(SPRING + BAY_SPAN / 2, LEVEL_HEIGHT), looks["Plaster"])
    if with_balustrade:
        write_mesh(stage, f"{path}/Balustrade", along_colonnades(balustrade_bay()), looks["Stone"])


def build():
    """Sponza-like courtyard: paved floor, walls, two colonnaded storeys, roof ring, cloths."""
    stage, looks = new_stage(UsdGeom.Tokens.y, 1.0, "Sponza-like atrium", MATERIALS, root="/World/Atrium")
    roof_top = 2 * LEVEL_HEIGHT
    floor, walls, parapet = MeshBuilder(), MeshBuilder(), MeshBuilder()
    floor.grid((0, 0, 0), Z, X, ticks([-OUTER[1], OUTER[1]], 1.0), ticks([-OUTER[0], OUTER[0]], 1.0))
    walls.box((-OUTER[0], 0, -OUTER[1]), (OUTER[0], roof_top, OUTER[1]), faces=SIDES,
              steps=(2.0, 1.5, 2.0), inward=True)
    for sz in (-1, 1):  # parapet along the courtyard edge of the roof
        z0, z1 = sorted((sz * HOLE[1], sz * (HOLE[1] + 0.3)))
        parapet.box((-HOLE[0] - 0.3, roof_top, z0), (HOLE[0] + 0.3, roof_top + 0.6, z1),
                    faces=faces_except("-y"), steps=(1.5, None, None))
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

    add_daylight(stage, (-58.0, 30.0, 0.0))  # 58 degrees up, so part of the courtyard floor is sunlit
    for k, position in enumerate(((-9.0, 10.5, 8.2), (9.0, 10.5, -8.2))):  # upper gallery lamps
        lamp = UsdLux.SphereLight.Define(stage, f"/World/Lights/GalleryLamp_{k}")
        lamp.CreateRadiusAttr(0.12)
        set_emission(lamp, 15.0, (1.0, 0.8, 0.6), exposure=3.0)
        lamp.AddTranslateOp().Set(Gf.Vec3d(*position))
    return stage
