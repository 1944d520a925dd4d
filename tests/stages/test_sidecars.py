"""Sidecar files (textures, .dds, .npz, streams): named by output and content so no output overwrites
another's, written atomically with their layer, and removed when the output that named them no
longer does; temporary files are recognisable, never outlive a failure, and stale ones of a killed
bake are removed by the next bake into the same output."""

import hashlib
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd

import fake_processors as fakes
import usdbake
from usdbake import core
from usdbake.cli.main import main
from usdbake.core import Attribute, File, Params, Processor, Result, Texture, param
from usdbake.stages import bake_layer, sidecars

SAMPLES = Path(__file__).resolve().parents[2] / "samples"


class FakeSidecars(Processor):
    """A texture and a raw file whose bytes are ``level``, each named by an asset attribute on the
    first prim; the texture path has a folder, as displacement_fields' has."""

    name = "fake_sidecars"
    facets = ("geometry",)
    writes = ("bake:fake:",)

    @dataclass(frozen=True)
    class Params(Params):
        level: int = param(1, "the byte every pixel and data byte holds", low=0, high=255)

    def run(self, ctx):
        prim = ctx.scene.prim_paths[0]
        level = ctx.params.level
        return Result(outputs=[
            Texture("fake/ground.png", np.full((4, 8, 1), level, np.uint8)),
            File("fake_data.bin", bytes([level]) * 16),
            Attribute(prim, "bake:fake:texture", "./fake/ground.png", "asset"),
            Attribute(prim, "bake:fake:data", "fake_data.bin", "asset"),
        ])


@pytest.fixture
def sidecar_processor():
    core.registry.registry()  # built-ins and entry points first, so teardown restores exactly this state
    core.registry.register(FakeSidecars)
    yield FakeSidecars.name
    core.registry.unregister(FakeSidecars.name)


def digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def bake(stage_in, out, level, cache, *extra) -> int:
    return main(["bake", str(stage_in), "-o", str(out), "-p", "fake_sidecars", "--cache", cache,
                 "--set", f"fake_sidecars.level={level}", *extra])


def assets(out) -> dict[str, Path]:
    """Asset attribute name -> resolved file, read from a fresh stage."""
    stage = Usd.Stage.Open(str(out))
    prim = stage.GetPrimAtPath("/World/Ground")
    found = {}
    for name in ("bake:fake:texture", "bake:fake:data"):
        value = prim.GetAttribute(name).Get()
        assert value.resolvedPath, f"{out}: {name} = {value.path} does not resolve"
        found[name] = Path(value.resolvedPath)
    return found


def assert_output_valid(out, level):
    import OpenImageIO as oiio

    files = assets(out)
    pixels = oiio.ImageBuf(str(files["bake:fake:texture"])).get_pixels(oiio.UINT8)
    np.testing.assert_array_equal(pixels, np.full((4, 8, 1), level, np.uint8))
    assert files["bake:fake:data"].read_bytes() == bytes([level]) * 16
    return files


def folder_files(folder) -> list[str]:
    return sorted(p.name for p in Path(folder).iterdir() if p.is_file())


def test_sidecars_are_named_by_output_stem_record_and_content(tmp_path, stage_in, cache, sidecar_processor):
    out = tmp_path / "atrium.baked.usda"
    assert bake(stage_in, out, 7, cache) == 0
    texture_hash = hashlib.sha256(b"|u1(4, 8, 1)" + bytes([7]) * 32).hexdigest()[:8]
    data_hash = hashlib.sha256(bytes([7]) * 16).hexdigest()[:8]
    texture = f"atrium.baked_fake_ground_{texture_hash}.png"
    data = f"atrium.baked_fake_data_{data_hash}.bin"
    assert folder_files(tmp_path) == sorted(["atrium.baked.usda", "in.usda", texture, data])
    files = assert_output_valid(out, 7)
    assert {name: path.name for name, path in files.items()} == {"bake:fake:texture": texture,
                                                                 "bake:fake:data": data}
    layer = Sdf.Layer.OpenAsAnonymous(str(out))
    assert list(dict(layer.customLayerData)["usdbake"]["sidecars"]) == [f"./{texture}", f"./{data}"]
    assert layer.GetAttributeAtPath("/World/Ground.bake:fake:texture").default.path == f"./{texture}"


def test_two_outputs_with_different_params_in_one_folder_both_stay_valid(tmp_path, stage_in, cache,
                                                                         sidecar_processor):
    before = digest(stage_in)
    assert bake(stage_in, tmp_path / "a.usda", 1, cache) == 0
    assert bake(stage_in, tmp_path / "b.usdc", 2, cache) == 0
    a, b = assert_output_valid(tmp_path / "a.usda", 1), assert_output_valid(tmp_path / "b.usdc", 2)
    assert not set(a.values()) & set(b.values())
    assert all(path.name.startswith("a_") for path in a.values())
    assert all(path.name.startswith("b_") for path in b.values())
    assert digest(stage_in) == before


def test_two_displacement_field_outputs_in_one_folder_both_stay_valid(tmp_path, cache):
    """The issue's case: field textures were named by prim path only, so a second bake rewrote the
    first output's PNG."""
    import OpenImageIO as oiio

    source = tmp_path / "props.usda"
    source.write_bytes((SAMPLES / "instanced_props.usda").read_bytes())
    before = digest(source)
    fields = {}
    for name, samples in (("a.usda", 64), ("b.usda", 81)):
        assert main(["bake", str(source), "-o", str(tmp_path / name), "-p", "displacement_fields",
                     "--cache", cache, "--set", f"displacement_fields.positional_samples={samples}",
                     "--set", "displacement_fields.direction_map_size=8"]) == 0
        stage = Usd.Stage.Open(str(tmp_path / name))
        fields[name] = {}
        for prim in stage.Traverse():
            if prim.HasAPI("DisplacementFieldAPI"):
                path = Path(prim.GetAttribute("bake:field:file").Get().resolvedPath)
                fields[name][str(prim.GetPath())] = (path, digest(path))
    assert fields["a.usda"].keys() == fields["b.usda"].keys() and fields["a.usda"]
    for prim, (path_a, hash_a) in fields["a.usda"].items():
        path_b, hash_b = fields["b.usda"][prim]
        assert path_a != path_b and hash_a != hash_b
        assert digest(path_a) == hash_a and digest(path_b) == hash_b  # the second bake left the first's alone
        for path in (path_a, path_b):
            assert oiio.ImageBuf(str(path)).spec().width > 0
    assert digest(source) == before


def test_rebake_removes_the_sidecars_it_no_longer_names(tmp_path, stage_in, cache, sidecar_processor):
    out = tmp_path / "out.usda"
    assert bake(stage_in, out, 1, cache) == 0
    first = assert_output_valid(out, 1)
    assert bake(stage_in, out, 2, cache) == 0
    second = assert_output_valid(out, 2)
    assert not any(path.exists() for path in first.values())
    assert folder_files(tmp_path) == sorted(["in.usda", "out.usda", *(p.name for p in second.values())])
    assert bake(stage_in, out, 2, cache) == 0  # unchanged: the same names, nothing removed
    assert assert_output_valid(out, 2) == second


def test_rebake_keeps_sidecars_another_output_of_the_same_stem_names(tmp_path, stage_in, cache,
                                                                    sidecar_processor):
    assert bake(stage_in, tmp_path / "a.usda", 1, cache) == 0
    assert bake(stage_in, tmp_path / "a.usdc", 1, cache) == 0  # same stem, same content: same names
    assert bake(stage_in, tmp_path / "a.usdc", 2, cache) == 0
    assert_output_valid(tmp_path / "a.usda", 1)
    assert_output_valid(tmp_path / "a.usdc", 2)


def test_rebake_of_an_output_without_recorded_digests_removes_nothing(tmp_path, stage_in, cache,
                                                                     sidecar_processor):
    """An older output listed no digests (or no sidecars at all, naming textures by prim path in a
    subfolder): nothing proves which files are its own, so the re-bake leaves every one of them."""
    out = tmp_path / "out.usda"
    old_texture = tmp_path / "displacement_fields" / "World_Ground.png"
    old_texture.parent.mkdir()
    old_texture.write_bytes(b"old png")
    (tmp_path / "usdbake_radiosity_0123456789.dds").write_bytes(b"old dds")
    layer = Sdf.Layer.CreateNew(str(out))
    layer.subLayerPaths.append("in.usda")
    layer.customLayerData = {"usdbake": {"version": "0.0.1", "source": "in.usda"}}
    prim = Sdf.CreatePrimInLayer(layer, "/World/Ground")
    for name, value in (("bake:field:file", "./displacement_fields/World_Ground.png"),
                        ("matrixFile", "usdbake_radiosity_0123456789.dds")):
        Sdf.AttributeSpec(prim, name, Sdf.ValueTypeNames.Asset).default = Sdf.AssetPath(value)
    layer.Save()
    assert bake(stage_in, out, 3, cache) == 0
    files = assert_output_valid(out, 3)
    assert folder_files(tmp_path) == sorted(["in.usda", "out.usda", "usdbake_radiosity_0123456789.dds",
                                             *(p.name for p in files.values())])
    assert old_texture.read_bytes() == b"old png"


def test_sidecar_digests_are_recorded(tmp_path, stage_in, cache, sidecar_processor):
    out = tmp_path / "out.usda"
    assert bake(stage_in, out, 5, cache) == 0
    provenance = dict(Sdf.Layer.OpenAsAnonymous(str(out)).customLayerData)["usdbake"]
    recorded = dict(zip(provenance["sidecars"], provenance["sidecarDigests"]))
    assert recorded == {name: digest(tmp_path / name) for name in provenance["sidecars"]} and recorded


def test_interrupt_while_renaming_leaves_the_previous_output_and_no_file_behind(tmp_path, stage_in, cache,
                                                                               sidecar_processor, capsys,
                                                                               monkeypatch):
    out = tmp_path / "out.usda"
    assert bake(stage_in, out, 1, cache) == 0
    before = {name: digest(tmp_path / name) for name in folder_files(tmp_path)}
    real_replace = os.replace
    calls = []

    def interrupted_replace(src, dst):
        if Path(dst).parent == tmp_path:  # not the result cache's own renames
            calls.append(Path(dst).name)
        if Path(dst) == out:  # every sidecar is in place; Ctrl-C lands before the layer's rename
            raise KeyboardInterrupt
        real_replace(src, dst)

    monkeypatch.setattr(bake_layer.os, "replace", interrupted_replace)
    capsys.readouterr()
    assert bake(stage_in, out, 2, cache) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "usdbake: interrupted; no output was written"
    assert len(calls) == 3  # two sidecars renamed, then the layer
    assert {name: digest(tmp_path / name) for name in folder_files(tmp_path)} == before
    assert_output_valid(out, 1)


def test_failed_image_write_leaves_only_the_previous_output(tmp_path, stage_in, cache, sidecar_processor,
                                                           capsys, monkeypatch):
    out = tmp_path / "out.usda"
    assert bake(stage_in, out, 1, cache) == 0
    before = {name: digest(tmp_path / name) for name in folder_files(tmp_path)}
    written = []

    def failing_write(pixels, path):
        written.append(Path(path))
        Path(path).write_bytes(b"half an image")
        raise KeyboardInterrupt

    monkeypatch.setattr(sidecars, "_write_image", failing_write)
    assert bake(stage_in, out, 2, cache) == 130
    # The temporary name is next to the output, recognisably usdbake's and this output's.
    assert [p.parent for p in written] == [tmp_path]
    assert written[0].name.startswith(f".out.usda.usdbake-tmp-{os.getpid()}-")
    assert written[0].name.endswith(".png")
    assert {name: digest(tmp_path / name) for name in folder_files(tmp_path)} == before


def test_a_later_bake_removes_the_temp_files_a_killed_bake_left(tmp_path, stage_in, cache, sidecar_processor):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    dead_pid = int(dead.stdout)  # a process that has exited: its pid names no running bake
    stale = [tmp_path / f".out.usda.usdbake-tmp-{dead_pid}-0a1b2c3d-out.usda",
             tmp_path / f".out.usda.usdbake-tmp-{dead_pid}-0a1b2c3d-out_fake_ground_12345678.png"]
    running = tmp_path / f".out.usda.usdbake-tmp-{os.getpid()}-4e5f6a7b-out.usda"  # a bake still running
    other = tmp_path / f".other.usda.usdbake-tmp-{dead_pid}-0a1b2c3d-other.usda"  # another output's
    for path in (*stale, running, other):
        path.write_bytes(b"partial")
    out = tmp_path / "out.usda"
    assert bake(stage_in, out, 1, cache) == 0
    assert not any(path.exists() for path in stale)
    assert running.exists() and other.exists()
    assert_output_valid(out, 1)


def test_hook_names_sidecars_by_stage_and_content_with_absolute_paths(tmp_path, cache, sidecar_processor):
    """An anonymous session layer anchors no relative path: the hook writes absolute ones."""
    stage_path = fakes.write_stage(tmp_path / "shot.usda")
    textures = tmp_path / "textures"
    stage = Usd.Stage.Open(stage_path)
    usdbake.bake(stage, ["fake_sidecars"], {"fake_sidecars": {"level": 5}}, cache_dir=cache,
                 texture_dir=str(textures))
    first = {name: Path(stage.GetPrimAtPath("/World/Ground").GetAttribute(name).Get().path)
             for name in ("bake:fake:texture", "bake:fake:data")}
    assert all(path.is_absolute() and path.parent == textures.resolve() and path.name.startswith("shot.usdbake_")
               for path in first.values())
    assert first["bake:fake:data"].read_bytes() == bytes([5]) * 16
    usdbake.bake(stage, ["fake_sidecars"], {"fake_sidecars": {"level": 6}}, cache_dir=cache,
                 texture_dir=str(textures))
    second = Path(stage.GetPrimAtPath("/World/Ground").GetAttribute("bake:fake:data").Get().path)
    assert second.read_bytes() == bytes([6]) * 16
    assert sorted(p.name for p in textures.iterdir()) == sorted(
        Path(stage.GetPrimAtPath("/World/Ground").GetAttribute(name).Get().path).name
        for name in ("bake:fake:texture", "bake:fake:data"))  # the first bake's files are gone


def test_hook_interrupted_while_authoring_takes_its_new_files_back(tmp_path, cache, sidecar_processor,
                                                                  monkeypatch):
    """In memory the sidecars are renamed into place before the layer names them; if authoring then
    fails, the files it would have named are removed again and the earlier bake's stay."""
    stage = Usd.Stage.Open(fakes.write_stage(tmp_path / "shot.usda"))
    textures = tmp_path / "textures"
    usdbake.bake(stage, ["fake_sidecars"], {"fake_sidecars": {"level": 5}}, cache_dir=cache,
                 texture_dir=str(textures))
    before = {p.name: digest(p) for p in textures.iterdir()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(bake_layer, "_author_attribute", interrupted)
    with pytest.raises(KeyboardInterrupt):
        usdbake.bake(stage, ["fake_sidecars"], {"fake_sidecars": {"level": 6}}, cache_dir=cache,
                     texture_dir=str(textures))
    assert {p.name: digest(p) for p in textures.iterdir()} == before
