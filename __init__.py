"""usdbake: precomputed lighting for OpenUSD stages with NVIDIA Warp kernels.

The repository root is this package, and this module is its Python front door: ``bake`` (into an open
stage, ``stages.hook``), ``bake_many`` (stage files, ``farm.batch``), ``irradiance_at`` (what a bake stored,
read back at points: ``stages.baked_irradiance`` and each technique's own lookup), ``init_warp`` and
``__version__``.
It sits above every folder: it may import any of them, and none imports it.
"""

import numpy as np

from .core.errors import StageError
from .core.version import __version__
from .kernels.startup import CUDA_DRIVER_NOTICE, init_warp
from .schemas import register as _register_schemas

# Register our schema plugin as early as possible: USD reads plugin schemas
# once, when the first stage is opened. In a DCC that opened stages before
# importing usdbake, set PXR_PLUGINPATH_NAME to usdbake/schemas instead.
SCHEMAS_REGISTERED = _register_schemas()


def bake(stage, processors=None, params=None, **options):
    """Bake into an open Usd.Stage; see usdbake.stages.hook.bake."""
    from .stages.hook import bake as _bake
    from .stages.inputs import check_device

    check_device(options.get("device", "cpu"), option="device=")  # before Warp starts on a device it may lack
    init_warp(options.get("device", "cpu"))
    return _bake(stage, processors=processors, params=params, **options)


def bake_many(paths, output_dir=None, **options):
    """Bake many stage files, one task per stage, locally or on a Dask cluster; see usdbake.farm.batch.bake_many."""
    from .farm.batch import bake_many as _bake_many

    init_warp(options.get("device", "cpu"))
    return _bake_many(paths, output_dir, **options)


def irradiance_at(stage, points, normals, source="auto", *, time=None, allow_partial=False, max_distance=None):
    """Irradiance a bake stored in ``stage``, read back at world points for unit normals; no light is computed.

    Parameters
    ----------
    stage : an open Usd.Stage or the path of a stage file; the composed stage is read, wherever the bake layer sits
        (a sublayer, the session layer's usdbake layer, a reference)
    points : (N, 3) world positions in the stage's units (``metersPerUnit`` plays no part: irradiance is
        W/m^2 whatever the length unit)
    normals : (N, 3) unit normals (world space) of the surfaces the irradiance falls on
    source : where to read it
        ``"light_probes"``   the first LightProbeCloud (a bake writes /usdbake/LightProbes): the L2 SH of
                             the tetrahedron holding the point, blended barycentrically (clamped outside
                             the hull, the stored blocked edges keeping light from leaking through walls),
                             evaluated at the normal
        ``"irradiance_grid"`` the first IrradianceVectorGrid (/usdbake/IrradianceGrid): its decoded vectors,
                             reconstructed as the bake did its ``primvars:bake:irradianceGrid``: the point
                             moved ``normal_offset`` cells along the normal, then the paper's (or the
                             normalized) formula, with the params the bake layer records (defaults
                             otherwise); at a baked mesh vertex it returns that primvar's value
        ``"radiosity"``      meshes with ``primvars:bake:irradianceDirect`` and ``...Indirect``: their sum
                             at the closest point on the baked triangles (world space, transforms applied),
                             blended barycentrically from the triangle's vertices. The normal only picks
                             among triangles equally near (an unwelded corner or seam, coincident surfaces):
                             those facing it most, their distinct points averaged; the values are those of
                             the baked surface whichever way it points
        ``"auto"``           the first of these three the stage holds
    time : time code to read the stage at (None: the default time)
    allow_partial : return what the bake stored where it left some light out: a probe cloud baked with
        ``direct_lights=lookup`` (``bake:directLights = excluded``) lacks the direct light of the stage's
        distant, sphere, rect and disk lights, which the bake leaves for the lookup to add by shadow rays
        (``processors.light_probes.interpolation.irradiance_at`` with a tracer; this reads and casts
        none); a grid baked with ``include_direct=false`` holds indirect light only. Without it such a
        source raises StageError
    max_distance : radiosity only: how far (stage units) a point may lie from every baked triangle;
        default 1e-3 of the baked surfaces' bounding-box diagonal

    Returns
    -------
    (N, 3) float64 irradiance E (W/m^2, linear RGB) at each point for its normal.

    Raises
    ------
    UsageError : points or normals not (N, 3), not finite, of different lengths, a normal not of unit
        length, a stage that is neither a Usd.Stage nor a readable file, an unknown source, a stage
        without that source (without any, for "auto"), a radiosity point beyond max_distance
    StageError : baked data that cannot be read (wrong sizes, another SH basis or order), or a partial
        source without ``allow_partial``; the message names prim, attribute and value
    """
    from .stages.baked_irradiance import check_queries, open_with_source

    points, normals = check_queries(points, normals)
    stage, found = open_with_source(stage, source)
    read = {"light_probes": _probe_irradiance, "irradiance_grid": _grid_irradiance,
            "radiosity": _radiosity_irradiance}[found]
    return read(stage, points, normals, time=time, allow_partial=allow_partial, max_distance=max_distance)


def _probe_irradiance(stage, points, normals, *, time, allow_partial, **_):
    from .processors.light_probes.interpolation import cloud_from_arrays, irradiance_at as cloud_irradiance
    from .stages.baked_irradiance import read_probe_cloud, to_local

    baked = read_probe_cloud(stage, time)
    if baked.lights_left_out and not allow_partial:
        raise StageError(baked.path, "bake:directLights", f"'excluded': the probes lack the direct light of "
                         f"{', '.join(baked.lights_left_out[:3])}{' ...' if len(baked.lights_left_out) > 3 else ''}, "
                         "left to be added at lookup by shadow rays, which irradiance_at does not cast; bake "
                         "light_probes with direct_lights=probes, read another source, or pass allow_partial=True "
                         "for the stored part only")
    init_warp("cpu")  # the tetrahedron walk is a Warp kernel
    centre = baked.probe_positions.mean(axis=0)  # float32 barycentrics about the cloud, not the stage origin
    capture = None if baked.capture_positions is None else baked.capture_positions - centre
    cloud = cloud_from_arrays(baked.probe_positions - centre, baked.probe_sh, baked.tet_vertices,
                              baked.tet_neighbors, baked.tet_blocked, capture_positions=capture)
    local, turned = to_local(baked.world_to_local, points, normals)
    return cloud_irradiance(cloud, local - centre, turned).astype(np.float64)


def _grid_irradiance(stage, points, normals, *, time, allow_partial, **_):
    from .kernels.direction24 import dequantize_vectors
    from .processors.irradiance_grid.irradiance_grid import IrradianceGrid
    from .processors.irradiance_grid.vector_grid import GridLayout, reconstruct_irradiance
    from .stages.baked_irradiance import read_vector_grid, to_local

    baked = read_vector_grid(stage, time)
    if not baked.include_direct and not allow_partial:
        raise StageError(baked.path, "bake:includeDirect", "false: the grid holds indirect light only; bake "
                         "irradiance_grid with include_direct=true, read another source, or pass allow_partial=True "
                         "for the stored part only")
    recorded = {name: baked.params[name] for name in ("normal_offset", "reconstruction", "behind_cutoff")
                if name in baked.params}
    try:
        options = IrradianceGrid.Params(**recorded)  # the processor's defaults for what is not recorded
    except ValueError as error:
        raise StageError(baked.path, "", f"the irradiance_grid params its bake layer records: {error}") from None
    layout = GridLayout(baked.grid_origin, baked.cell_size, baked.resolution)
    local, turned = to_local(baked.world_to_local, points, normals)
    return reconstruct_irradiance(layout, dequantize_vectors(baked.directions, baked.colors), local, turned,
                                  normal_offset=options.normal_offset, reconstruction=options.reconstruction,
                                  behind_cutoff=options.behind_cutoff).astype(np.float64)


def _radiosity_irradiance(stage, points, normals, *, time, max_distance, **_):
    from .processors.radiosity.vertex_lookup import surface_values_at
    from .stages.baked_irradiance import read_radiosity_surfaces

    baked = read_radiosity_surfaces(stage, time)
    return surface_values_at(points, normals, baked.points, baked.triangles, baked.point_irradiance,
                             max_distance=max_distance)


__all__ = ["CUDA_DRIVER_NOTICE", "bake", "bake_many", "init_warp", "irradiance_at", "__version__"]
