"""``usdbake preview``: render the baked data of a stage to an image.

Stage -> Scene (``extract_scene``, so a refined mesh authored by a bake is
what gets drawn); the baked channel mapped onto the Scene's triangles as
per-corner values (``channels.read_channel``); a camera from a
UsdGeom.Camera or framed automatically (``camera``); probe and grid points
as spheres; then ``raycast.trace_frame``, ``render.shade`` and
``images.write_image``. Everything read off the stage comes through
``usdbake.stages`` (``extract`` and ``baked_data``): no pxr here.

Scalar channels default to false colour with a legend, colour channels to
shading + tone mapping (see ``color`` for the curve).
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

import numpy as np

from ..core.errors import UsageError
from ..core.scene import Scene
from ..kernels.rgb9e5 import decode_rgb9e5
from ..kernels.sh import BAND, SH_COUNT, evaluate_np
from ..kernels.tracer import Tracer
from ..stages.baked_data import open_stage, read_camera, read_probe_clouds, read_vector_grids
from ..stages.extract import extract_scene
from .camera import Camera, auto_camera
from .channels import read_channel, sample_textures
from .images import compare_with, write_image
from .legend import legend_width
from .raycast import Frame, choose_auto_camera, trace_frame
from .render import headlight, shade

STYLES = ("auto", "falsecolor", "shaded")
SPHERE_RADIUS_RELATIVE = 0.004
"""Probe / grid spheres: radius as a fraction of the scene diagonal (visible at 640 x 480, small enough
not to hide each other in a typical probe spacing)."""

SPHERE_ALBEDO = 0.8
"""Probe / grid spheres are drawn as Lambertian spheres of this albedo."""

CONDON_SHORTLEY_SIGN = (-1.0) ** (np.arange(SH_COUNT) - BAND * (BAND + 1))
"""(9,) (-1)^m of each coefficient (m = k - l (l + 1)): turns SH in the Condon-Shortley convention into
``kernels.sh``'s basis, which has no such phase."""


# ---------------------------------------------------------------------------
# Cameras


def camera_from_stage(stage, path: str, scene: Scene, time: float | None = None) -> Camera:
    """The Camera of the UsdGeom.Camera at ``path`` (focal length, apertures, offsets, transform)."""
    record = read_camera(stage, path, time)
    matrix = record.camera_to_world.copy()
    matrix[3, :3] -= scene.origin
    return Camera(**dict(vars(record), camera_to_world=matrix))


# ---------------------------------------------------------------------------
# Probes and grids


@dataclass
class Spheres:
    """Probe or grid points to draw as spheres."""

    centers: np.ndarray
    """(S, 3) float32 scene-local."""
    colors: np.ndarray
    """(S, 3) float32 linear colour (headlight-shaded)."""
    sh: np.ndarray | None = None
    """(S, 9, 3) float32 SH irradiance coefficients (probes), evaluated at each pixel's sphere normal."""
    condon_shortley: bool = False
    """``sh`` carries the Condon-Shortley phase (see CONDON_SHORTLEY_SIGN)."""
    source: str = ""
    """Paths of the prims drawn, comma separated."""


def _to_local(world_positions: np.ndarray, scene: Scene) -> np.ndarray:
    return (world_positions - scene.origin).astype(np.float32)


def probe_spheres(stage, scene: Scene, time) -> Spheres | None:
    """Probe positions of every LightProbeCloud, with their SH coefficients when present."""
    clouds = read_probe_clouds(stage, time)
    if not clouds:
        return None
    points = np.concatenate([_to_local(c.probe_positions, scene) for c in clouds])
    sh = [np.zeros((len(c.probe_positions), SH_COUNT, 3), np.float32) if c.probe_sh is None
          else real_orthonormal(c.probe_sh, c.condon_shortley) for c in clouds]  # each cloud in its own basis
    return Spheres(points, np.full((len(points), 3), SPHERE_ALBEDO, np.float32), np.concatenate(sh), False,
                   ", ".join(c.path for c in clouds))


def real_orthonormal(sh: np.ndarray, condon_shortley: bool) -> np.ndarray:
    """(N, 9, 3) float32 coefficients in the real orthonormal basis (without the Condon-Shortley phase)."""
    sh = np.asarray(sh, np.float32)
    return sh * CONDON_SHORTLEY_SIGN[:, None].astype(np.float32) if condon_shortley else sh


def grid_spheres(stage, scene: Scene, time) -> Spheres | None:
    """Vertices of every IrradianceVectorGrid, coloured by the mean of their decoded vectors."""
    grids = read_vector_grids(stage, time)
    if not grids:
        return None
    centers, colors = [], []
    for grid in grids:
        count, per_vertex, packed = len(grid.vertex_positions), grid.vectors_per_vertex, grid.vertex_colors_rgb9e5
        if per_vertex > 0 and len(packed) == count * per_vertex:
            color = decode_rgb9e5(packed).reshape(count, per_vertex, 3).mean(axis=1)
        else:
            color = np.full((count, 3), SPHERE_ALBEDO, np.float32)
        centers.append(_to_local(grid.vertex_positions, scene))
        colors.append(color.astype(np.float32))
    return Spheres(np.concatenate(centers), np.concatenate(colors), None, False, ", ".join(g.path for g in grids))


def sh_irradiance(sh: np.ndarray, normals: np.ndarray, condon_shortley: bool = False) -> np.ndarray:
    """(N, 3) float32 value of L2 SH ``sh`` ((N, 9, 3)) at unit ``normals`` ((N, 3)), real orthonormal basis."""
    return evaluate_np(real_orthonormal(sh, condon_shortley), np.asarray(normals, np.float32)).astype(np.float32)


def _extra_spheres(stage, scene: Scene, time, probes: bool, grid: bool, messages: list) -> Spheres | None:
    found = []
    for wanted, read, missing in (
            (probes, probe_spheres, "--probes: no LightProbeCloud prim with probePositions in the stage"),
            (grid, grid_spheres, "--grid: no IrradianceVectorGrid prim with a resolution in the stage")):
        if not wanted:
            continue
        spheres = read(stage, scene, time)
        if spheres is None:
            messages.append(f"{missing}; nothing to draw")
        else:
            found.append(spheres)
    if not found:
        return None
    if len(found) == 1:
        return found[0]
    sh = [s.sh if s.sh is not None else np.zeros((len(s.centers), SH_COUNT, 3), np.float32) for s in found]
    return Spheres(np.concatenate([s.centers for s in found]), np.concatenate([s.colors for s in found]),
                   np.concatenate(sh), found[0].condon_shortley, ", ".join(s.source for s in found))


def _sphere_colors(spheres: Spheres, frame: Frame, height: int, width: int) -> np.ndarray:
    """(S, 3) colours lit by the headlight, or (H, W, 3) per-pixel colours when the probes carry SH."""
    on = frame.sphere >= 0
    if spheres.sh is None or not on.any() or not np.any(spheres.sh):
        return spheres.colors
    index = frame.sphere[on]
    # SH irradiance E(n) at the sphere normal, shown as a Lambertian sphere: L = albedo E / pi.
    # Spheres without SH keep their colour under the headlight.
    lit = SPHERE_ALBEDO * np.maximum(sh_irradiance(spheres.sh[index], frame.sphere_normal[on],
                                                   spheres.condon_shortley), 0.0) / np.pi
    plain = spheres.colors[index] * headlight(frame.facing[on])[:, None]
    per_pixel = np.zeros((height, width, 3), np.float32)
    per_pixel[on] = np.where(np.any(spheres.sh[index] != 0, axis=(1, 2))[:, None], lit, plain)
    return per_pixel


# ---------------------------------------------------------------------------
# The command


def parse_size(text: str) -> tuple[int, int]:
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text or "")
    if not match:
        raise UsageError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 640x480")
    width, height = int(match[1]), int(match[2])
    if not (1 <= width <= 16384 and 1 <= height <= 16384):
        raise UsageError(f"--size {text}: width and height must be within 1..16384")
    return width, height


def preview(stage, output: str, *, camera: str | None = None, channel: str | None = None,
            time: float | None = None, size: tuple[int, int] = (640, 480), exposure: float | None = None,
            style: str = "auto", value_range: tuple[float, float] | None = None, legend: bool = True,
            wire: bool = False, probes: bool = False, grid: bool = False, compare: str | None = None,
            orbit: tuple[float, float] | None = None, device: str = "cpu") -> dict:
    """Render ``stage`` (a path or an open Usd.Stage) to ``output`` (.png or .exr).

    Returns a report: what was drawn, messages, timings, the RMS difference with ``--compare``, and
    the Image under ``"image"``.

    camera : path of a UsdGeom.Camera, or None for the automatic three-quarter view.
    orbit : (azimuth, elevation) in degrees for the automatic view (azimuth from the stage's front
        axis, +Z for Y-up and -Y for Z-up, towards +X); None tries the front, back and side views
        and keeps the one that sees the most surface.
    """
    import time as clock

    started = clock.perf_counter()
    if camera and orbit is not None:
        raise UsageError("--camera and --orbit exclude each other (--orbit places the automatic camera)")
    if style not in STYLES:
        raise UsageError(f"--style {style!r}: expected one of {', '.join(STYLES)}")
    width, height = size
    timings: dict[str, float] = {}
    mark = [clock.perf_counter()]

    def lap(name: str) -> None:
        now = clock.perf_counter()
        timings[name] = now - mark[0]
        mark[0] = now

    stage_obj = open_stage(stage)
    scene = extract_scene(stage_obj, time=time)
    report: dict = {"output": output, "messages": list(scene.warnings), "timings": timings}
    lap("read_stage")
    if scene.num_triangles == 0:
        report["messages"].append("the stage has no renderable meshes; the image shows only the background")

    data = read_channel(stage_obj, scene, channel, time) if channel else None
    lap("read_channel")
    if data is not None:
        report["messages"] += data.messages
        report["attributes"] = data.attributes
    mode = "albedo"
    if data is not None:
        mode = style if style != "auto" else ("falsecolor" if data.components == 1 else "shaded")
        if mode == "falsecolor" and data.components != 1:
            raise UsageError(f"--style falsecolor needs a scalar channel; {channel} has 3 components")
    lo, hi = (value_range if value_range is not None else ((data.lo, data.hi) if data is not None else (0.0, 1.0)))
    if value_range is not None and not lo < hi:
        raise UsageError(f"--range {lo} {hi}: the low end must be below the high end")
    panel = legend_width(lo, hi, height) if mode == "falsecolor" and legend else 0
    view_width = width - panel
    if view_width < 1:
        raise UsageError(f"--size {width}x{height}: too narrow for the legend ({panel} px); use --no-legend")

    tracer = Tracer.from_scene(scene, device=device)
    lap("build_bvh")
    if camera:
        cam = camera_from_stage(stage_obj, camera, scene, time).conformed(view_width, height)
        report["camera"] = camera
    elif orbit is not None:
        if not -90.0 <= orbit[1] <= 90.0:
            raise UsageError(f"--orbit {orbit[0]:g} {orbit[1]:g}: elevation must be within -90..90 degrees")
        lo_b, hi_b = scene.bounds
        cam = auto_camera(lo_b, hi_b, scene.up_axis, view_width, height, azimuth_deg=orbit[0],
                          elevation_deg=orbit[1]).conformed(view_width, height)
        report["camera"] = f"auto (azimuth {orbit[0]:g}, elevation {orbit[1]:g})"
    else:
        cam = choose_auto_camera(tracer, scene, view_width, height)
        report["camera"] = "auto"

    spheres = _extra_spheres(stage_obj, scene, time, probes, grid, report["messages"])
    lap("camera")
    frame = trace_frame(
        tracer, scene, cam, view_width, height,
        corner_values=data.corner_values if data is not None else None, wire=wire,
        spheres=spheres.centers if spheres is not None else None,
        sphere_radius=SPHERE_RADIUS_RELATIVE * max(scene.diagonal, 1e-9))
    if data is not None and data.textures is not None:  # a lightmap: the traced values are UVs
        covered = frame.hit_triangle >= 0
        covered &= data.tri_has_value[np.where(covered, frame.hit_triangle, 0)]
        frame = dataclasses.replace(frame, value=sample_textures(data, frame.value, covered))
    image = shade(
        frame, scene.tri_albedo, tri_has_value=data.tri_has_value if data is not None else None,
        channels=data.components if data is not None else 1, style=mode, value_range=(lo, hi),
        label=channel or "", exposure=exposure, irradiance=bool(data and data.irradiance), legend=legend,
        legend_panel=panel if panel else None,
        sphere_colors=_sphere_colors(spheres, frame, height, view_width) if spheres is not None else None)
    lap("render")

    if compare:
        image, report["rms"] = compare_with(compare, image)
    write_image(output, image, channel or "value")
    lap("write_image")
    report.update({
        "mode": mode, "size": [width, height], "view_width": view_width, "exposure": image.exposure,
        "range": [lo, hi] if mode == "falsecolor" else None, "triangles": scene.num_triangles,
        "spheres": 0 if spheres is None else len(spheres.centers), "seconds": clock.perf_counter() - started,
    })
    report["image"] = image
    return report

