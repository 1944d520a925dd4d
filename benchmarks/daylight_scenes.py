"""Daylight scenes of issue 29 (interreflections, glazing, photometry): the LM-83 office and what both scenes share.

Two stages, Z-up, metres, x east, y north (usdbake's ``enu_to_world('Z')`` with ``north`` 0, Radiance's
frame in ``radiance_scene``), every face's material a UsdPreviewSurface bound to its mesh
(``diffuseColor``; glass: ``inputs:opacity`` = 1 - VLT and a float ``bake:transmittance`` = VLT on the
glass mesh prim, so either reading of ``stages/materials.py`` finds the VLT):

``lm83_office()`` (here)
    An IES LM-83-style side-lit office, 6 m wide (x) x 10 m deep (y) x 3 m high, its one glazed facade
    facing **south** (the y = 0 wall, the window's outward normal -y). Window band: sill 0.9 m, head
    2.4 m, 4.8 m wide centred (x 0.6 .. 5.4): window-to-wall ratio 7.2 / 18 = 0.40. Reflectances (grey):
    floor 0.2, walls 0.5, ceiling 0.7; one glass pane of VLT 0.6 fills the opening. Walls, floor and
    ceiling are **single faces facing into the room** (no thickness, no reveals), the box closed by the
    glass; no ground in the stage (gendaymtx and usdbake's ground parameter add one of 0.2 below the
    horizon). Sensors: LM-83 puts them on a work plane 0.76 m high on a 0.6 m grid; usdbake reports per
    face of receiving meshes, so the **floor** is the sensor surface here: a 0.6 m grid (10 x 17 = 170
    points, 0.3 m from the walls, at the centres of the floor's 0.2 m cells), 1 mm above the floor,
    normals up. The floor is tessellated in 0.2 m squares (``floor_cell``), so each sensor lies in a face
    of its own (on the diagonal shared by the two triangles of a square: ``sample_baked`` averages faces
    that contain a point).

``furnished_daylight_room()`` (``furnished_daylight_room``)
    A furnished living room of our own on a 200 m ground, lit by a uniform sky: see that module.

Each returns a ``DaylightScene``; its first six fields unpack as (stage, sensor_points, sensor_normals,
triangles, albedo, transmittance). The Radiance side reads the geometry back from the stage with pxr
(``stage_readback.stage_triangles``: world positions, fan-triangulated faces, bound materials), not from the
generator, so both sides see the same triangles. ``stage_readback.sample_baked`` reads usdbake's per-face
results of a baked stage at the sensor points. ``daylight_references.office_reference`` and
``furnished_reference`` compute the Radiance references (cached in benchmarks/cache by
``harness.cached_reference``). Shared here: ``DaylightScene``, ``SCENES_VERSION``, ``SENSOR_OFFSET`` and the
glass material (``GLASS_REFLECTANCE``, ``_glass_material``, ``_write_glass``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade

from . import harness
from .stage_readback import TRANSMITTANCE_ATTR, stage_triangles

sys.path.insert(0, str(harness.SAMPLES))  # the samples' mesh and stage helpers (samples/ is not a package)
from mesh_builder import X, Z, MeshBuilder, ticks  # noqa: E402
from stage_authoring import make_material, new_stage, write_mesh  # noqa: E402

SCENES_VERSION = 1
"""Bump when a scene's geometry or materials change (part of the reference cache keys)."""
SENSOR_OFFSET = 1e-3
"""Metres: sensors and random points are traced from 1 mm off their surface, along the normal."""


# --------------------------------------------------------------------------- the LM-83 office

OFFICE_SIZE = (6.0, 10.0, 3.0)
"""Width (x, along the facade), depth (y, away from it), height (z), metres."""
OFFICE_WINDOW = ((0.6, 5.4), (0.9, 2.4))
"""The window opening in the south wall (y = 0): (x range, z range), metres: 7.2 m^2 of 18 m^2."""
OFFICE_REFLECTANCE = {"Floor": 0.2, "Walls": 0.5, "Ceiling": 0.7}
OFFICE_VLT = 0.6
OFFICE_SENSOR_SPACING = 0.6
"""LM-83's grid spacing (metres); the first row and column 0.3 m from the walls."""
GLASS_REFLECTANCE = 0.1
"""diffuseColor authored on glass: about the hemispherical reflectance of Radiance ``glass`` of VLT 0.6-0.7
(n = 1.52, ~0.06 at normal incidence, rising at grazing angles). Radiance reflects it specularly and ignores
this value; a diffuse reader gets the same energy back."""


@dataclass(frozen=True)
class DaylightScene:
    """A stage, its sensors and its geometry as the Radiance side reads it back (``stage_triangles``).

    Unpacks as (stage, sensor_points, sensor_normals, triangles, albedo, transmittance)."""

    stage: Usd.Stage
    sensor_points: np.ndarray
    """(S, 3) float64 world positions (metres), on (or, for the office floor, 1 mm above) their surface."""
    sensor_normals: np.ndarray
    """(S, 3) float64 unit normals of the sensors' surfaces."""
    triangles: np.ndarray
    """(T, 3, 3) float64 world positions of every triangle of every mesh (fan-triangulated faces)."""
    albedo: np.ndarray
    """(T, 3) float64 RGB diffuse reflectance (the bound UsdPreviewSurface's diffuseColor)."""
    transmittance: np.ndarray
    """(T,) float64 VLT at normal incidence: ``bake:transmittance``, else 1 - opacity; 0 opaque."""
    sensor_prims: tuple = ()
    """(S,) prim path of the mesh each sensor lies on."""
    tri_prim: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """(T,) int64 index into ``prim_paths`` of each triangle's mesh."""
    prim_paths: tuple = ()
    """The mesh prim paths, in ``stage_triangles`` order."""

    def __iter__(self):
        return iter((self.stage, self.sensor_points, self.sensor_normals, self.triangles, self.albedo,
                     self.transmittance))


def _glass_material(stage, name: str, vlt: float):
    """A UsdPreviewSurface glass: opacity = 1 - VLT, ior 1.52, diffuseColor ``GLASS_REFLECTANCE``; the VLT also
    as ``bake:transmittance`` on the Material."""
    material = make_material(stage, name, (GLASS_REFLECTANCE,) * 3, 0.0)
    shader = UsdShade.Shader(stage.GetPrimAtPath(f"/World/Looks/{name}/PreviewSurface"))
    shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(float(1.0 - vlt))
    shader.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(1.52)
    material.GetPrim().CreateAttribute(TRANSMITTANCE_ATTR, Sdf.ValueTypeNames.Float).Set(float(vlt))
    return material


def _write_glass(stage, path: str, builder: MeshBuilder, material, vlt: float):
    mesh = write_mesh(stage, path, builder, material)
    mesh.GetPrim().CreateAttribute(TRANSMITTANCE_ATTR, Sdf.ValueTypeNames.Float).Set(float(vlt))
    return mesh


def office_stage(*, floor_cell: float = 0.2, surface_cell: float = 0.5, vlt: float = OFFICE_VLT) -> Usd.Stage:
    """The LM-83-style office (module docstring), in memory; floor in ``floor_cell`` squares, walls and
    ceiling in cells of about ``surface_cell`` metres."""
    w, d, h = OFFICE_SIZE
    (wx0, wx1), (wz0, wz1) = OFFICE_WINDOW
    looks = {name: ((r, r, r), 0.9) for name, r in OFFICE_REFLECTANCE.items()}
    stage, mats = new_stage(UsdGeom.Tokens.z, 1.0, "IES LM-83-style side-lit office (issue 29)", looks,
                            root="/World/Office")
    glass = _glass_material(stage, "Glass", vlt)
    floor, ceiling, walls, pane = MeshBuilder(), MeshBuilder(), MeshBuilder(), MeshBuilder()
    lo, hi = (0.0, 0.0, 0.0), (w, d, h)
    steps = lambda cell: (cell, cell, cell)  # noqa: E731
    floor.box(lo, hi, faces=("-z",), steps=steps(floor_cell), inward=True)
    ceiling.box(lo, hi, faces=("+z",), steps=steps(surface_cell), inward=True)
    walls.box(lo, hi, faces=("+y", "-x", "+x"), steps=steps(surface_cell), inward=True)
    # South wall (y = 0, facing +y into the room): a grid over the window's stops, the opening skipped.
    zs = _ticks([0.0, wz0, wz1, h], surface_cell)
    xs = _ticks([0.0, wx0, wx1, w], surface_cell)
    opening = {(i, j) for i in range(len(zs) - 1) for j in range(len(xs) - 1)
               if wz0 <= zs[i] < wz1 and wx0 <= xs[j] < wx1}
    walls.grid((0.0, 0.0, 0.0), Z, X, zs, xs, skip=opening)
    pane.grid((0.0, 0.0, 0.0), Z, X, [wz0, wz1], [wx0, wx1])  # the glass, facing into the room
    for name, builder in (("Floor", floor), ("Ceiling", ceiling), ("Walls", walls)):
        write_mesh(stage, f"/World/Office/{name}", builder, mats[name])
    _write_glass(stage, "/World/Office/Glazing", pane, glass, vlt)
    return stage


def _ticks(stops, step: float) -> np.ndarray:
    """Values through every stop, at most ``step`` apart."""
    return ticks(stops, step)


def office_sensors(spacing: float = OFFICE_SENSOR_SPACING, height: float = SENSOR_OFFSET
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(S, 3) float64 floor sensors on the LM-83 grid (``height`` above the floor) and their (S, 3) up normals,
    row by row from the window (y) and west to east (x)."""
    w, d, _ = OFFICE_SIZE
    xs = np.arange(spacing / 2, w, spacing)
    ys = np.arange(spacing / 2, d, spacing)
    gy, gx = np.meshgrid(ys, xs, indexing="ij")
    points = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, height)])
    return points, np.tile([0.0, 0.0, 1.0], (len(points), 1))


def lm83_office(*, floor_cell: float = 0.2, surface_cell: float = 0.5, vlt: float = OFFICE_VLT) -> DaylightScene:
    """The office stage, its floor sensors and its triangles read back from the stage."""
    stage = office_stage(floor_cell=floor_cell, surface_cell=surface_cell, vlt=vlt)
    points, normals = office_sensors()
    geometry = stage_triangles(stage)
    return DaylightScene(stage, points, normals, geometry.triangles, geometry.albedo, geometry.transmittance,
                         sensor_prims=("/World/Office/Floor",) * len(points), tri_prim=geometry.tri_prim,
                         prim_paths=geometry.prim_paths)


def window_to_wall_ratio(scene: DaylightScene, wall_normal=(0.0, 1.0, 0.0)) -> float:
    """Glazed area / (glazed + opaque area) of the wall whose inward normal is ``wall_normal``, from the
    triangles (the facade: opaque faces in the plane of the glass with that normal)."""
    tri = scene.triangles
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(2.0 * area, 1e-300)[:, None]
    glazed = scene.transmittance > 0
    plane = float(tri[glazed][:, :, 1].mean())  # the facade's y
    facade = (normal @ np.asarray(wall_normal) > 0.99) & (np.abs(tri[:, :, 1] - plane).max(axis=1) < 1e-6)
    return float(area[facade & glazed].sum() / area[facade].sum())

