"""Daylight for the browser: the refined faces' daylight coefficients written as a stream file.

The sky-visibility paper's point is interactivity (Bosch, Besuievsky & Martin, Sec. 5: visibility
precomputed so any sky relights at interactive rates). This processor packs what relights a face with
no rays (``kernels/daylight_relight.py``'s ``Relighter``): the sky visibility factors V, the
interreflection's indirect coefficients D and ground terms, and a sun table (the sun's visibility on a
declination x hour-angle grid over its yearly path at the site's latitude: ``daylight.sun_table``), with
the refined mesh, albedo, site and north, and the scene's other triangles (instances, prims that are
not receivers: the interreflection's transport faces) for context, into ``formats/daylight_stream.py``'s file. ``usdbake serve``
streams it after the geometry; the viewer relights it on the GPU for any date, hour and sky, and
``preview/stream_client.py`` relights it as the library does.

USD written (bake layer): ``/usdbake/DaylightStream`` (Scope) with ``streamFile`` (asset, the sidecar
``<layer>_daylight_<hash>.bin``), ``bake:faces`` (int), ``bake:bytesPerFace`` (float) and
``bake:indirectError`` (float: largest error of D's 8-bit square-root codes, as a share of each
face's largest D).

Parameters: ``usdbake list daylight_stream`` or docs/processors.md, both generated from ``Params`` below.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core import Attribute, Context, File, Prim, Processor, Result, param
from ...formats.daylight_stream import (DaylightCoefficients, decode_indirect, encode_daylight_stream,
                                        indirect_codes)
from ...formats.weather import check_site, read_weather
from ...kernels.daylight_relight import sky_model_tables
from ...kernels.sky import patch_samples
from .daylight import SiteParams, sun_table
from .glazing import scene_glazing
from .interreflection import transport_faces
from .products import InterreflectionProduct, SkyVisibilityProduct

STREAM_PRIM = "/usdbake/DaylightStream"
STREAM_FILE = "daylight.bin"


def stream_coefficients(scene, product: SkyVisibilityProduct, inter: InterreflectionProduct, table, *,
                        site: dict, weather=None) -> DaylightCoefficients:
    """The stream's arrays: the product's faces in order, V as the bake's own uint8 codes."""
    prims = [{"path": scene.prim_paths[prim], "faces": int((product.face_prim == prim).sum())}
             for prim in product.prims]
    prim_index = np.zeros(int(max(product.prims.max(initial=0), product.face_prim.max(initial=0))) + 1, np.int64)
    prim_index[product.prims] = np.arange(len(product.prims))
    context = transport_faces(scene, product)  # the triangles light bounces off that are not faces here
    header = {
        "patches": {"layout": product.patches.layout, "count": len(product.patches),
                    "subdivision": int(product.patches.subdivision)},
        "visibility_scale": float(product.visibility_scale), "bounces": int(inter.bounces),
        "ground_reflectance": float(inter.ground_reflectance), "site": site,
        "to_world": product.to_world.tolist(), "origin": np.asarray(scene.origin, np.float64).tolist(),
        "up_axis": product.up_axis, "prims": prims,
        "sun_table": {"declinations": table.declinations.tolist(), "hour_angles": table.hour_angles.tolist(),
                      "node_row": table.node_row.tolist(), "samples": int(table.samples)},
        # the weather file by name only: the stream goes to anyone who opens the page, its folders need not
        "sky_tables": sky_model_tables(),
        "weather": {"source": Path(weather.source).name, "hours": len(weather.times)} if weather is not None else None,
    }
    return DaylightCoefficients(
        header, patch_samples(product.patches, 3), product.patches.patch_solid_angles,
        product.patches.patch_directions, product.face_points.astype(np.float32),
        product.face_vertices.astype(np.uint32), product.face_normals.astype(np.float32),
        scene.tri_albedo[product.face_source].astype(np.float32), product.visibility, inter.sky_indirect,
        inter.ground_direct, inter.ground_indirect, np.ascontiguousarray(table.hits.T),
        prim_index[product.face_prim].astype(np.uint32), weather.times if weather is not None else None,
        weather.direct_normal if weather is not None else None,
        weather.diffuse_horizontal if weather is not None else None,
        context.corners[context.outputs:], scene.tri_albedo[context.extra_triangles])


def indirect_code_error(indirect: np.ndarray) -> float:
    """Largest error of D's square-root codes (``formats/daylight_stream.indirect_codes``), as a share of the
    face's largest D."""
    if not indirect.size:
        return 0.0
    scale, codes = indirect_codes(indirect)
    error = np.abs(decode_indirect(codes, scale) - indirect) / np.where(scale > 0, scale, 1.0)[..., None]
    return float(error.max())


class DaylightStream(Processor):
    name = "daylight_stream"
    version = "1"
    summary = "Daylight coefficients (sky, sun table, interreflection) of the refined faces as a browser stream."
    facets = ("geometry", "materials")
    writes = ("/usdbake/DaylightStream",)
    requires = (SkyVisibilityProduct, InterreflectionProduct)

    @dataclass(frozen=True)
    class Params(SiteParams):
        weather: str = param("", "typical-year weather file (.epw or TMY3 .csv) whose 8760 hours the viewer "
                             "can pick; its site replaces latitude, longitude and timezone")
        declination_step: float = param(4.0, "sun table: declination spacing, degrees", low=0.5, high=23.45)
        hour_step: float = param(3.75, "sun table: hour-angle spacing, degrees (3.75 = 15 minutes)", low=0.25,
                                 high=30.0)
        sun_samples: int = param(4, "shadow rays per face and sun table node", low=1, high=255)
        packet_faces: int = param(2048, "faces per packet of the stream", low=64, high=1 << 20)
        seed: int = param(0, "random seed of the sun rays", low=0)

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        product = ctx.products[SkyVisibilityProduct]
        inter = ctx.products[InterreflectionProduct]
        weather = read_weather(p.weather) if p.weather else None
        if weather is not None:
            check_site(weather, scene.site)
        site = {"latitude": weather.latitude if weather else p.latitude,
                "longitude": weather.longitude if weather else p.longitude,
                "timezone": weather.timezone if weather else p.timezone, "north": p.north}
        table = sun_table(ctx.tracer, product, latitude=site["latitude"], north=p.north,
                          declination_step=p.declination_step, hour_step=p.hour_step, samples=p.sun_samples,
                          seed=p.seed, glazing=scene_glazing(scene, ctx.tracer), progress=ctx.progress)
        data = encode_daylight_stream(stream_coefficients(scene, product, inter, table, site=site, weather=weather),
                                      packet_faces=p.packet_faces)
        faces = max(product.num_faces, 1)
        error = indirect_code_error(inter.sky_indirect)
        result = Result(stats={"faces": float(product.num_faces), "bytes_per_face": len(data) / faces,
                               "sun_table_nodes": float(len(table.hits)), "indirect_code_error": error})
        result.outputs += [
            Prim("/usdbake", "Scope"), Prim(STREAM_PRIM, "Scope"),
            Attribute(STREAM_PRIM, "streamFile", f"./{STREAM_FILE}", "asset"),
            Attribute(STREAM_PRIM, "bake:faces", int(product.num_faces), "int"),
            Attribute(STREAM_PRIM, "bake:bytesPerFace", float(len(data) / faces), "float"),
            Attribute(STREAM_PRIM, "bake:indirectError", error, "float"),
            File(STREAM_FILE, data),
        ]
        result.messages.append(f"daylight stream: {product.num_faces} faces, {len(data) / 2 ** 20:.1f} MiB "
                               f"({len(data) / faces:.0f} B/face), sun table {len(table.hits)} nodes")
        return result
