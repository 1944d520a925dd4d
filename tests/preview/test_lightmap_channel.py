"""Lightmap channels in the preview: a mesh's ``bake:lightmap:<name>:file`` read through its UVs."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, UsdGeom
from stage_builders import add_mesh, new_stage, write_png

from usdbake.preview.channels import Channel, read_channel, sample_textures
from usdbake.preview.compose import preview
from usdbake.stages.extract import extract_scene


def test_sample_textures_reads_texel_centres_exactly_with_v_up_and_repeat_wrap():
    image = np.arange(12, dtype=np.float32).reshape(3, 4, 1)  # row 0 is v = 0
    channel = Channel("x", np.zeros((0, 3, 3)), np.zeros(0, bool), 1, 0.0, 11.0, False, textures=[image])
    uv = np.array([[[0.125, 1 / 6, 0], [0.875, 5 / 6, 0], [1.125, 1 / 6, 0], [0.25, 1 / 6, 0]]], np.float32)
    values = sample_textures(channel, uv, np.ones((1, 4), bool))[0, :, 0]
    np.testing.assert_allclose(values, [0.0, 11.0, 0.0, 0.5], atol=1e-5)  # (x, y) = (0, 0), (3, 2), wrap, blend


def test_a_lightmap_channel_is_read_through_the_meshes_uvs(tmp_path):
    """A floor whose lightmap is 0.2 where v < 0.5 and 0.8 above, its st upside down (v = 1 - z): the corners
    carry the UVs and the preview reads both values."""
    pixels = np.zeros((64, 64, 1), np.uint8)
    pixels[:32], pixels[32:] = 204, 51  # file rows are top first: the top half (v > 0.5) is 0.8
    write_png(tmp_path / "lightmap.png", pixels)
    stage = new_stage(up_axis="Y")
    floor = add_mesh(stage, "/World/Floor", [(0, 0, 0), (0, 0, 1), (1, 0, 1), (1, 0, 0)], [4], [0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(floor).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set([(0, 1), (0, 0), (1, 0), (1, 1)])
    prim = floor.GetPrim()
    prim.CreateAttribute("bake:lightmap:ao:file", Sdf.ValueTypeNames.Asset).Set(str(tmp_path / "lightmap.png"))
    prim.CreateAttribute("bake:lightmap:ao:uv", Sdf.ValueTypeNames.Token).Set("st")
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "ao")
    assert channel.textures is not None and channel.tri_has_value.all()
    assert abs(channel.lo - 0.2) < 0.01 and abs(channel.hi - 0.8) < 0.01
    assert abs(channel.textures[0][0, 0, 0] - 0.2) < 0.01  # row 0 is v = 0: the file's bottom row
    z = scene.points[scene.tri_vertices][..., 2] - scene.points[:, 2].min()  # the scene frame is centred
    np.testing.assert_allclose(channel.corner_values[..., 1], 1 - z, atol=1e-6)
    report = preview(stage, str(tmp_path / "ao.png"), channel="ao", size=(120, 90), legend=False)
    values = report["image"].value[..., 0]
    lit = values[values > 0]
    near = (np.abs(lit - 0.2) < 0.02) | (np.abs(lit - 0.8) < 0.02)
    assert near.mean() > 0.8 and (np.abs(lit - 0.2) < 0.02).any() and (np.abs(lit - 0.8) < 0.02).any()
