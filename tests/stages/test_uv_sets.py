"""UV sets read per triangle corner for the texture target: every interpolation, indexed or not; unusable
sets left out with a warning naming prim, primvar and value."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, UsdGeom
from stage_builders import add_mesh, new_stage

from usdbake.stages.extract import extract_scene

QUAD = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]


def quad_with(name: str, interpolation: str, values, indices=None):
    stage = new_stage()
    mesh = add_mesh(stage, "/World/Quad", QUAD, [4], [0, 1, 2, 3])
    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(name, Sdf.ValueTypeNames.TexCoord2fArray, interpolation)
    primvar.Set(values)
    if indices is not None:
        primvar.SetIndices(indices)
    return extract_scene(stage)


def corner_uv_of_points(scene) -> dict:
    """{point index: UV} over every triangle corner (a quad's UVs follow its points here)."""
    return {int(v): tuple(np.round(scene.tri_st[t, k], 6)) for t in range(scene.num_triangles)
            for k, v in enumerate(scene.tri_vertices[t])}


def test_indexed_face_varying_and_vertex_sets_give_each_corner_its_uv():
    expected = {0: (0.0, 0.0), 1: (1.0, 0.0), 2: (1.0, 1.0), 3: (0.0, 1.0)}
    indexed = quad_with("st", UsdGeom.Tokens.faceVarying, [(1, 1), (0, 0), (1, 0), (0, 1)], [1, 2, 0, 3])
    vertex = quad_with("st", UsdGeom.Tokens.vertex, [(0, 0), (1, 0), (1, 1), (0, 1)])
    for scene in (indexed, vertex):
        assert scene.prim_st == ("st",) and corner_uv_of_points(scene) == expected


def test_a_second_set_is_the_lightmap_set():
    scene = quad_with("st1", UsdGeom.Tokens.vertex, [(0, 0), (0.5, 0), (0.5, 0.5), (0, 0.5)])
    assert scene.prim_lightmap_uv == ("st1",) and scene.prim_st == ("",)
    assert scene.tri_lightmap_uv.max() == 0.5


def test_unusable_sets_are_left_out_with_a_warning_naming_them():
    nan = quad_with("st", UsdGeom.Tokens.faceVarying, [(0, 0), (float("nan"), 0), (1, 1), (0, 1)])
    assert nan.prim_st == ("",) and np.isfinite(nan.tri_st).all()
    assert any("/World/Quad: primvars:st holds" in line and "at 1" in line for line in nan.warnings)
    bad_index = quad_with("st", UsdGeom.Tokens.faceVarying, [(0, 0), (1, 0)], [0, 1, 5, 0])
    assert bad_index.prim_st == ("",)
    assert any("primvars:st:indices: index 5 at position 2" in line for line in bad_index.warnings)
    short = quad_with("st", UsdGeom.Tokens.faceVarying, [(0, 0), (1, 0)])
    assert short.prim_st == ("",) and any("has 2 values where the topology needs 4" in w for w in short.warnings)
