"""The sky-lit furnished rooms of issue 30 and their test points.

Two rooms, each under two skies (``room_stage(name, sky, folder)``):

``daylight_room``
    ``furnished_daylight_room.room_stage(glazed=False)``: the living room of issue 29 (~129k triangles, 200 m
    ground) with its four windows **open** (radiosity, irradiance_grid and light_probes read a pane as an
    opaque surface, so the panes are left out on both sides).
``furnished_room``
    ``furnished_room.build()``: the benchmarks' furnished room (four open windows, 200 m ground).

Skies: ``uniform``, a DomeLight of constant radiance (the daylight room's ``SKY_RADIANCE`` = 1000 / pi, the
furnished room's own dome of 10 W/(m^2 sr)); ``perez``, the layer ``usdbake sky`` writes (``PEREZ``: Greensboro
NC, 21 March 14:00 local standard time, DNI 600 / DHI 150 W/m^2, Perez efficacy: a lat-long DomeLight and a
0.53 degree DistantLight sun; the sun enters the south and west windows), the uniform dome removed. Each stage
gets a probe volume (an invisible Cube with ProbeVolumeAPI) on the room's interior box, so the grid and the
probes fill the room rather than the 200 m ground (the authoring a user of the CLI would do; no parameter
changes).

Test points (``test_points``, fixed seeds, the same for both skies), world frame: ``surface`` area-uniform on
the opaque faces inside the room whose point 1 mm off the face is in free space (radiosity's rows);
``free`` uniform in the room shrunk by 2 cm, outside geometry and >= 10 cm from it, 6 rows each (the axis
normals); ``near`` 5 cm off area-uniform surface points along the face normal (``probe_reference``'s
samplers, which use usdbake's tracer to pick points only; no value comes from it).
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import furnished_daylight_room as fdr
from . import furnished_room as fr

SCENES = ("daylight_room", "furnished_room")
SKIES = ("uniform", "perez")
PEREZ = {"time": "2026-03-21T14:00", "latitude": 36.07, "longitude": -79.79, "timezone": -5.0, "dni": 600.0,
         "dhi": 150.0}
"""``usdbake sky --model perez`` options: Greensboro NC (the TMY3 site of the daylight benchmarks)."""
ROOM_BOXES = {"daylight_room": (fdr.ROOM_LO, fdr.ROOM_HI), "furnished_room": (fr.ROOM_LO, fr.ROOM_HI)}
SHRINK = 0.02
"""Free points stay this far (m) inside the room's box (``probe_reference.ROOM_SHRINK``)."""
SURFACE_OFFSET = 1e-3
"""Surface rows are traced by Radiance 1 mm off their face (``daylight_scenes.SENSOR_OFFSET``)."""
SEED = 30
"""Fixed seed of the test points (issue 30)."""


def room_stage(name: str, sky: str, folder: str | Path):
    """The stage of room ``name`` under ``sky``, written to ``folder`` (the sky layer and its .exr beside it)
    and opened from there."""
    from pxr import Gf, Usd, UsdGeom

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if name == "daylight_room":
        stage = fdr.room_stage(glazed=False, dome_light=(sky == "uniform"))
    elif name == "furnished_room":
        stage = fr.build()
        if sky != "uniform":
            stage.RemovePrim("/World/Lights/Sky")
    else:
        raise ValueError(f"unknown room {name!r}, expected one of {SCENES}")
    if sky not in SKIES:
        raise ValueError(f"unknown sky {sky!r}, expected one of {SKIES}")
    lo, hi = ROOM_BOXES[name]
    volume = UsdGeom.Cube.Define(stage, "/World/ProbeVolume")
    volume.CreateSizeAttr(1.0)
    volume.AddTranslateOp().Set(Gf.Vec3d(*((lo + hi) / 2).tolist()))
    volume.AddScaleOp().Set(Gf.Vec3f(*(hi - lo).tolist()))
    volume.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    volume.GetPrim().AddAppliedSchema("ProbeVolumeAPI")
    base = folder / f"{name}_{sky}_room.usda"  # one file per sky: USD keeps an opened layer per path
    stage.GetRootLayer().Export(str(base))
    if sky == "uniform":
        return Usd.Stage.Open(str(base))
    layer = folder / f"{name}_{sky}.usda"
    command = [sys.executable, "-m", "usdbake.cli.main", "sky", str(base), "-o", str(layer), "--model", "perez",
               "--time", PEREZ["time"], "--latitude", str(PEREZ["latitude"]), "--longitude",
               str(PEREZ["longitude"]), "--timezone", str(PEREZ["timezone"]), "--dni", str(PEREZ["dni"]),
               "--dhi", str(PEREZ["dhi"])]
    subprocess.run(command, check=True, capture_output=True)
    return Usd.Stage.Open(str(layer))


@dataclass(frozen=True)
class TestPoints:
    """World-frame rows at which irradiance is compared."""

    surface_points: np.ndarray
    """(S, 3) float64 on their faces."""
    surface_normals: np.ndarray
    """(S, 3) float64 unit face normals."""
    free_points: np.ndarray
    """(F, 3) float64; each is compared at the 6 ``AXIS_NORMALS``."""
    near_points: np.ndarray
    """(M, 3) float64, 5 cm off their face."""
    near_normals: np.ndarray
    """(M, 3) float64 unit face normals."""

    def rows(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """{kind: (positions (R, 3), normals (R, 3))}; free rows are point-major, 6 normals each."""
        from .probe_reference import AXIS_NORMALS

        axes = len(AXIS_NORMALS)
        free = (np.repeat(self.free_points, axes, axis=0),
                np.tile(AXIS_NORMALS.astype(np.float64), (len(self.free_points), 1)))
        return {"surface": (self.surface_points, self.surface_normals), "free": free,
                "near": (self.near_points, self.near_normals)}

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def test_points(name: str, stage, *, surface: int, free: int, near: int, seed: int = SEED) -> TestPoints:
    """The rows of room ``name`` (module docstring) on ``stage`` (either sky: the geometry is the same)."""
    from usdbake.kernels.light_bundles import scene_lighting
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.light_probes.capture import classify_points
    from usdbake.stages.extract import extract_scene

    from . import harness
    from . import probe_reference as ref

    scene = extract_scene(stage)
    tracer = Tracer.from_scene(scene)
    lighting = scene_lighting(scene, tracer.device)
    lo, hi = (np.asarray(b, np.float64) - scene.origin for b in ROOM_BOXES[name])
    boxes = [(lo + SHRINK, hi - SHRINK)]
    centres = scene.points[scene.tri_vertices].astype(np.float64).mean(axis=1)
    inside = np.all((centres >= lo - 1e-3) & (centres <= hi + 1e-3), axis=1)
    found, total, attempt = [], 0, 0
    while total < surface:  # drop points whose 1 mm offset lies inside a solid (a bed's footprint on the floor)
        p, n = harness.surface_points(scene, 2 * surface + 32, seed=seed + 7919 * attempt, triangles=inside)
        keep = ~classify_points(tracer, lighting, (p + 2e-3 * n).astype(np.float32))[0]
        found.append((p[keep], n[keep]))
        total += int(keep.sum())
        attempt += 1
    s_p = np.concatenate([f[0] for f in found])[:surface]
    s_n = np.concatenate([f[1] for f in found])[:surface]
    p_free = ref.free_points(scene, tracer, lighting, boxes, free, np.random.default_rng([seed, 0]))
    p_near, n_near = ref.near_points(scene, tracer, lighting, boxes, near, seed + 1)
    world = lambda p: np.asarray(p, np.float64) + scene.origin  # noqa: E731
    unit = lambda n: np.asarray(n, np.float64) / np.linalg.norm(n, axis=1, keepdims=True)  # noqa: E731
    return TestPoints(world(s_p), unit(s_n), world(p_free), world(p_near), unit(n_near))
