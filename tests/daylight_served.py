"""A window_room baked with daylight_stream (the Greensboro TMY3 year attached), and the library's relighter
for the same products: shared by the daylight viewer's browser test and the streaming benchmark's check."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from repo_paths import SAMPLES

STREAM = {"declination_step": 8.0, "hour_step": 7.5, "sun_samples": 8, "packet_faces": 128}
"""A coarse sun table keeps the test quick (the relighter below uses the same); small packets make the
1508-face stream progressive."""
CASES = [("2026-06-21", 12.0, "preetham"), ("2026-12-21", 12.0, "preetham"), ("2026-03-20", 9.5, "preetham"),
         ("2026-09-23", 16.25, "preetham"), ("2026-06-21", 7.0, "perez"), ("2026-01-15", 11.0, "perez"),
         ("2026-04-10", 14.5, "overcast"), ("2026-10-05", 10.0, "overcast"), ("2026-08-01", 18.5, "uniform"),
         ("2026-02-28", 13.0, "uniform")]
"""(date, local standard hour, sky): the browser against the library."""


def tmy3() -> Path:
    import pvlib

    return Path(pvlib.__file__).parent / "data" / "723170TYA.CSV"


def params(weather: Path | None) -> dict:
    values = dict(STREAM, **({"weather": str(weather)} if weather else {}))
    return {"daylight_stream": values}


def bake_daylight(folder: Path, weather: Path | None) -> Path:
    """``usdbake bake samples/window_room.usda -p daylight_stream`` into ``folder``; with ``weather`` also
    ``-p annual_daylight`` on that year (the viewer's overlays)."""
    from usdbake.cli.main import main

    out = folder / "room.usdc"
    settings = [f"daylight_stream.{k}={v}" for k, v in params(weather)["daylight_stream"].items()]
    annual = ["-p", "annual_daylight", "--set", f"annual_daylight.weather={weather}"] if weather else []
    code = main(["bake", str(SAMPLES / "window_room.usda"), "-o", str(out), "-p", "daylight_stream", *annual,
                 "--cache", str(folder / "cache"), *sum((["--set", s] for s in settings), [])])
    assert code == 0
    return out


@dataclass
class Library:
    relighter: object
    """``daylight.DaylightRelighter`` of the bake's own products and sun table."""
    stream: bytes
    """The stream the in-process run wrote (the CLI bake's sidecar must hold the same bytes)."""
    areas: np.ndarray
    normals: np.ndarray
    centroids: np.ndarray
    prims: list[str]
    """Prim path of each face (bake face order)."""

    def at(self, date: str, hour: float, sky: str) -> np.ndarray:
        return self.relighter.at(local_time(date, hour), sky=sky)


def local_time(date: str, hour: float) -> np.datetime64:
    return np.datetime64(date) + np.timedelta64(int(round(hour * 60)), "m")


def library(weather: Path | None) -> Library:
    """The same bake in-process: its sky visibility and interreflection products, relit by the library."""
    from pxr import Usd

    from usdbake.core.records import File
    from usdbake.core.runtime import Runtime
    from usdbake.core.pipeline import Pipeline
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.daylight.daylight import DaylightRelighter, sun_table
    from usdbake.processors.daylight.glazing import scene_glazing
    from usdbake.processors.daylight.products import InterreflectionProduct, SkyVisibilityProduct
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(Usd.Stage.Open(str(SAMPLES / "window_room.usda")))
    steps = Pipeline.build(["daylight_stream"], params(weather), runtime=Runtime(Tracer.from_scene)).run(scene)
    products = {kind: value for step in steps if step.result for kind, value in step.result.products.items()}
    product, inter = products[SkyVisibilityProduct], products[InterreflectionProduct]
    stream = next(r.data for step in steps if step.name == "daylight_stream" for r in step.result.outputs
                  if isinstance(r, File))
    header_site = _site(stream)
    tracer = Tracer.from_scene(scene)
    table = sun_table(tracer, product, latitude=header_site["latitude"], north=header_site["north"],
                      declination_step=STREAM["declination_step"], hour_step=STREAM["hour_step"],
                      samples=STREAM["sun_samples"], glazing=scene_glazing(scene, tracer))
    relighter = DaylightRelighter(product, table, latitude=header_site["latitude"],
                                  longitude=header_site["longitude"], timezone=header_site["timezone"],
                                  north=header_site["north"], interreflection=inter)
    corners = product.face_points[product.face_vertices]
    return Library(relighter, stream, product.face_areas.astype(np.float64), product.face_normals,
                   corners.mean(axis=1), [scene.prim_paths[p] for p in product.face_prim])


def _site(stream: bytes) -> dict:
    import json
    import struct

    length = struct.unpack_from("<I", stream, 8)[0]
    return json.loads(stream[12:12 + length])["site"]
