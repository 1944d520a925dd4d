"""The result cache: plain arrays + JSON that round-trip every processor's Result and never run code on load.

Entries are tampered with the way someone with write access to a shared cache folder could (pickles
in every file the cache reads, object arrays behind a matching hash): nothing may run, the step is
recomputed with a warning, and the entry is rewritten. A manifest edited by hand fails the entry's
hash; one resealed after the edit must still fit the scene (record sizes against points, faces,
corners and instances). Concurrent writers of one entry never leave a reader a broken or foreign
entry. A cache that cannot be written (no space, a size limit, a read-only folder) warns once and
the run completes.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import io
import json
import multiprocessing
import os
import pickle
import threading
import time
import warnings

import numpy as np
import pytest
from pxr import Usd
from repo_paths import SAMPLES
from stress.stage_builders_stress import FAST_PARAMS

import fake_processors as fakes
from read_only import ReadOnly
from usdbake import core
from usdbake.core import plain_data
from usdbake.core.cache import STALE_SECONDS, CacheWarning, ResultCache, entry_sha256, misfit
from usdbake.core.pipeline import Pipeline
from usdbake.core.processor import Processor, Result
from usdbake.core.products import RefinedScene
from usdbake.processors.daylight.products import SkyVisibilityProduct
from usdbake.processors.instancing.products import InstanceOcclusionProduct
from usdbake.processors.occlusion.products import AmbientOcclusionProduct
from usdbake.core.records import Attribute, Block, File, Primvar
from usdbake.core.runtime import Runtime
from usdbake.kernels.tracer import Tracer
from usdbake.core.scene import FACETS
from usdbake.stages.extract import extract_scene

AO_FAST = {"ambient_occlusion": {"samples": 4}}


@pytest.fixture(scope="module")
def cornell():
    return extract_scene(Usd.Stage.Open(str(SAMPLES / "cornell_box.usda")))


@pytest.fixture
def no_cache_warnings():
    """Turn a CacheWarning into an error: where an entry must load, a warning is a failure."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        yield


def assert_same(a, b, where="value"):
    """Equal types and values all the way down; arrays equal in dtype, shape, bytes and the read-only flag."""
    assert type(a) is type(b), f"{where}: {type(a).__name__} != {type(b).__name__}"
    if isinstance(a, np.ndarray):
        assert (a.dtype, a.shape, a.flags.writeable) == (b.dtype, b.shape, b.flags.writeable), where
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif dataclasses.is_dataclass(a) and not isinstance(a, type):
        for f in dataclasses.fields(a):
            if f.compare:
                assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            assert_same(a[key], b[key], f"{where}[{key!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{k}]")
    elif isinstance(a, (float, np.floating)) and np.isnan(a):
        assert np.isnan(b), where
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def params_for(*names: str) -> dict:
    merged: dict = {}
    for name in names:
        merged.update(FAST_PARAMS.get(name, {}))
    return merged


def actions(steps) -> dict:
    return {step.name: step.action for step in steps}


# ---------------------------------------------------------------------------
# Every processor's Result round-trips through the cache


@pytest.mark.parametrize("sample, names", [
    # sky_visibility provides RefinedScene (a whole Scene); ambient_occlusion then runs on it.
    ("cornell_box", ("sky_visibility", "daylight", "ambient_occlusion")),
    ("cornell_box", ("form_factors", "radiosity")),  # File records, CompressedOperator
    ("cornell_box", ("light_probes",)),  # Tetrahedralization inside ProbeCloud
    ("cornell_box", ("irradiance_grid",)),  # GridLayout
    ("cornell_box", ("progressive_mesh",)),  # dict of (array, array) tuples
    ("instanced_props", ("displacement_fields", "instance_ao")),  # dicts keyed by time codes
])
def test_second_run_is_served_from_the_cache_record_for_record(sample, names, tmp_path, no_cache_warnings):
    scene = extract_scene(Usd.Stage.Open(str(SAMPLES / f"{sample}.usda")))
    params = params_for(*names)
    first = Pipeline.build(list(names), params, runtime=Runtime(Tracer.from_scene), cache_dir=tmp_path)
    assert set(actions(first.run(scene)).values()) == {"run"}
    second = Pipeline.build(list(names), params, runtime=Runtime(Tracer.from_scene), cache_dir=tmp_path)
    assert set(actions(second.run(scene)).values()) == {"cached"}

    before, after = first.outputs(), second.outputs()
    assert len(before) == len(after) and before
    for k, (a, b) in enumerate(zip(before, after)):
        assert_same(a, b, f"outputs[{k}]")
    for a, b in zip(first.steps, second.steps):
        assert_same(a.result, b.result, a.name)
    assert not list(tmp_path.glob(".*"))  # no temporary files left


def test_a_cached_scene_and_memo_fields_behave_like_the_originals(cornell, tmp_path, no_cache_warnings):
    names, params = ["sky_visibility"], params_for("sky_visibility")
    first = Pipeline.build(names, params, runtime=Runtime(Tracer.from_scene), cache_dir=tmp_path).run(cornell)[0].result
    second = Pipeline.build(names, params, runtime=Runtime(Tracer.from_scene), cache_dir=tmp_path).run(cornell)[0]
    assert second.action == "cached"
    refined, loaded = first.products[RefinedScene].scene, second.result.products[RefinedScene].scene
    for facet in FACETS:
        assert loaded.fingerprint((facet,)) == refined.fingerprint((facet,))
    assert loaded.diagonal == refined.diagonal
    assert all(not array.flags.writeable for array in vars(loaded).values() if isinstance(array, np.ndarray))

    # A memo field is made afresh, not stored, and fills again as the original's does.
    visibility = second.result.products[SkyVisibilityProduct]
    assert visibility._cache == {}
    np.testing.assert_array_equal(visibility.visibility_float(),
                                  first.products[SkyVisibilityProduct].visibility_float())


# ---------------------------------------------------------------------------
# Tampered and corrupt entries: nothing runs, the step is recomputed, the entry rewritten


class Payload:
    """Unpickling it creates ``marker``: proof that a load ran code."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


def entry(cache_dir, scene) -> tuple[str, str]:
    """(name, key) of the ambient_occlusion entry for ``scene``."""
    step = Pipeline.build(["ambient_occlusion"], AO_FAST, runtime=Runtime(Tracer.from_scene),
                          cache_dir=cache_dir).plan(scene)[0]
    return step.name, step.key


def bake(cache_dir, scene) -> str:
    steps = Pipeline.build(["ambient_occlusion"], AO_FAST, runtime=Runtime(Tracer.from_scene),
                           cache_dir=cache_dir).run(scene)
    return steps[0].action


def manifest_and_arrays(cache_dir, scene):
    cache = ResultCache(cache_dir)
    name, key = entry(cache_dir, scene)
    manifest = cache.manifest_path(name, key)
    digest = json.loads(manifest.read_text())["arrays_sha256"]
    return manifest, cache.arrays_path(name, key, digest)


def reseal(manifest, content: dict) -> None:
    """Write ``content`` as the manifest with its entry hash recomputed: what someone who knows the
    format would plant, so the checks after the hash are what must catch it."""
    manifest.write_text(json.dumps({**content, "sha256": entry_sha256(content)}))


def legacy_pickle(cache_dir, scene, marker):
    """The format before this one, planted before any run."""
    name, key = entry(cache_dir, scene)
    cache_dir.mkdir(parents=True, exist_ok=True)
    (cache_dir / f"{name}-{key}.pkl").write_bytes(pickle.dumps(Payload(marker)))


def npz_is_a_pickle(cache_dir, scene, marker):
    manifest, arrays = manifest_and_arrays(cache_dir, scene)
    arrays.write_bytes(pickle.dumps(Payload(marker)))


def manifest_is_a_pickle(cache_dir, scene, marker):
    manifest, arrays = manifest_and_arrays(cache_dir, scene)
    manifest.write_bytes(pickle.dumps(Payload(marker)))


def object_array_behind_a_matching_hash(cache_dir, scene, marker):
    """What a writer who knows the format would plant: an object array, named and hashed as the manifest says."""
    manifest, _ = manifest_and_arrays(cache_dir, scene)
    buffer = io.BytesIO()
    np.savez(buffer, a0=np.array([Payload(marker)], dtype=object))
    data = buffer.getvalue()
    digest = hashlib.sha256(data).hexdigest()
    content = json.loads(manifest.read_text())
    content["arrays_sha256"] = digest
    name, key = content["processor"], content["key"]
    (cache_dir / f"{name}-{key}.{digest[:16]}.npz").write_bytes(data)
    reseal(manifest, content)


def dataclass_outside_usdbake(cache_dir, scene, marker):
    manifest, _ = manifest_and_arrays(cache_dir, scene)
    content = json.loads(manifest.read_text())
    content["tree"] = {"$": "dataclass", "type": "subprocess:Popen", "fields": {"args": ["touch", str(marker)]}}
    reseal(manifest, content)


def test_the_planted_payloads_would_run_code(tmp_path):
    """The tampering below is real: unpickling the payload, or loading its object array with pickles allowed,
    creates the marker."""
    marker = tmp_path / "marker"
    pickle.loads(pickle.dumps(Payload(marker)))
    assert marker.exists()
    marker.unlink()
    buffer = io.BytesIO()
    np.savez(buffer, a0=np.array([Payload(marker)], dtype=object))
    buffer.seek(0)
    np.load(buffer, allow_pickle=True)["a0"]
    assert marker.exists()


@pytest.mark.parametrize("tamper, warned", [
    (legacy_pickle, None),  # the old format is never read
    (npz_is_a_pickle, "content hash mismatch"),
    (manifest_is_a_pickle, "not a JSON manifest"),
    (object_array_behind_a_matching_hash, "Object arrays cannot be loaded"),
    (dataclass_outside_usdbake, "not from usdbake"),
])
def test_a_tampered_entry_runs_nothing_and_is_recomputed(tamper, warned, cornell, tmp_path):
    cache_dir, marker = tmp_path / "cache", tmp_path / "marker"
    if tamper is not legacy_pickle:
        assert bake(cache_dir, cornell) == "run"
    tamper(cache_dir, cornell, marker)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert bake(cache_dir, cornell) == "run"
    cache_warnings = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    if warned is None:
        assert cache_warnings == []
    else:
        assert len(cache_warnings) == 1
        assert cache_warnings[0].startswith("usdbake cache: ") and warned in cache_warnings[0]
        assert cache_warnings[0].endswith("; recomputing") and "\n" not in cache_warnings[0]
    assert not marker.exists()

    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        assert bake(cache_dir, cornell) == "cached"  # the entry was rewritten
    assert not marker.exists()


def truncated(manifest, arrays):
    arrays.write_bytes(arrays.read_bytes()[:-100])


def truncated_with_its_hash(manifest, arrays):
    """A corrupt zip the manifest vouches for: numpy refuses it."""
    data = arrays.read_bytes()[:200]
    content = json.loads(manifest.read_text())
    content["arrays_sha256"] = hashlib.sha256(data).hexdigest()
    arrays.with_name(f"{content['processor']}-{content['key']}.{content['arrays_sha256'][:16]}.npz").write_bytes(data)
    reseal(manifest, content)


def one_byte_flipped(manifest, arrays):
    data = bytearray(arrays.read_bytes())
    data[len(data) // 2] ^= 0xFF
    arrays.write_bytes(bytes(data))


def arrays_missing(manifest, arrays):
    arrays.unlink()


def manifest_of_another_entry(manifest, arrays):
    content = json.loads(manifest.read_text())
    content["key"] = "0" * 32
    manifest.write_text(json.dumps(content))


def manifest_of_another_format(manifest, arrays):
    content = json.loads(manifest.read_text())
    content["format"] = 99
    manifest.write_text(json.dumps(content))


def array_of_another_shape(manifest, arrays):
    text = manifest.read_text()
    reseal(manifest, json.loads(text.replace('"shape":[', '"shape":[7,', 1)))


def a_typo_in_the_manifest(manifest, arrays):
    """One character, in a field no other check reads: only the entry hash sees it."""
    text = manifest.read_text()
    assert text.count('"type_name":"float"') > 1
    manifest.write_text(text.replace('"type_name":"float"', '"type_name":"flaot"', 1))


def values_swapped_between_prims(manifest, arrays):
    """Two records' arrays exchanged in the tree: each still decodes, every array is the one hashed."""
    content = json.loads(manifest.read_text())
    first, second = content["tree"]["fields"]["outputs"][:2]
    first["fields"]["values"], second["fields"]["values"] = second["fields"]["values"], first["fields"]["values"]
    manifest.write_text(json.dumps(content))


def product_type_moved(where: str):
    """An entry written before its product type moved (to ``where``, a module that lacks it or none at all)."""
    def corrupt(manifest, arrays):
        text = manifest.read_text()
        now = "usdbake.processors.occlusion.products:AmbientOcclusionProduct"
        assert now in text
        reseal(manifest, json.loads(text.replace(now, f"{where}:AmbientOcclusionProduct")))
    corrupt.__name__ = f"product_type_moved_from_{where}"
    return corrupt


def manifest_without_its_hash(manifest, arrays):
    content = json.loads(manifest.read_text())
    del content["sha256"]
    manifest.write_text(json.dumps(content))


def manifest_with_a_number_json_cannot_hold(manifest, arrays):
    """1e999 parses as inf, which no JSON the cache writes can hold: the hash cannot even be taken."""
    manifest.write_text(manifest.read_text().replace('"element_size":1', '"element_size":1e999', 1))


@pytest.mark.parametrize("corrupt, warned", [
    (truncated, "content hash mismatch"),
    (truncated_with_its_hash, "unreadable arrays"),
    (one_byte_flipped, "content hash mismatch"),
    (arrays_missing, "arrays file unreadable"),
    (manifest_of_another_entry, "the manifest is for"),
    (manifest_of_another_format, "format 99"),
    (array_of_another_shape, "cannot decode"),
    (product_type_moved("usdbake.core.products"), "is not a dataclass type of usdbake.core.products"),
    (product_type_moved("usdbake.processors.occlusion.former"), "No module named"),
    (a_typo_in_the_manifest, "entry hash mismatch (the manifest was edited)"),
    (values_swapped_between_prims, "entry hash mismatch (the manifest was edited)"),
    (manifest_without_its_hash, "entry hash mismatch (the manifest was edited)"),
    (manifest_with_a_number_json_cannot_hold, "entry hash mismatch (the manifest was edited)"),
])
def test_a_corrupt_entry_warns_and_is_recomputed(corrupt, warned, cornell, tmp_path):
    cache_dir = tmp_path / "cache"
    assert bake(cache_dir, cornell) == "run"
    corrupt(*manifest_and_arrays(cache_dir, cornell))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert bake(cache_dir, cornell) == "run"
    cache_warnings = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert len(cache_warnings) == 1 and warned in cache_warnings[0], cache_warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        assert bake(cache_dir, cornell) == "cached"


def test_a_missing_entry_loads_as_none_silently(tmp_path, no_cache_warnings):
    assert ResultCache(tmp_path).load("ambient_occlusion", "0" * 32) is None
    assert not ResultCache(tmp_path).has("ambient_occlusion", "0" * 32)
    assert ResultCache(None).load("ambient_occlusion", "0" * 32) is None
    assert not ResultCache(None).has("ambient_occlusion", "0" * 32)


def test_the_entry_hash_is_of_the_content_not_the_bytes(cornell, tmp_path, no_cache_warnings):
    """A manifest re-indented (opened and saved by an editor) holds the same entry: still served."""
    cache_dir = tmp_path / "cache"
    assert bake(cache_dir, cornell) == "run"
    manifest, _ = manifest_and_arrays(cache_dir, cornell)
    content = json.loads(manifest.read_text())
    manifest.write_text(json.dumps(dict(reversed(list(content.items()))), indent=2))
    assert bake(cache_dir, cornell) == "cached"


# ---------------------------------------------------------------------------
# A decoded entry must fit the scene: record sizes against points, faces, corners and instances


@pytest.fixture(scope="module")
def cornell_ao(cornell):
    """A real ambient_occlusion Result on the Cornell box (Floor: 9 points, 4 quads; LightQuad: 4 points)."""
    return Pipeline.build(["ambient_occlusion"], AO_FAST, runtime=Runtime(Tracer.from_scene)).run(cornell)[0].result


def with_outputs(result: Result, *outputs) -> Result:
    return dataclasses.replace(result, outputs=list(outputs))


FLOOR, LIGHT = "/World/CornellBox/Floor", "/World/CornellBox/LightQuad"


def ao(prim: str, values, interpolation: str = "vertex", **fields) -> Primvar:
    return Primvar(prim, "bake:ao", np.asarray(values, np.float32), "float", interpolation, **fields)


@pytest.mark.parametrize("outputs, why", [
    ([ao(LIGHT, np.ones(9))], f"{LIGHT}: 9 vertex values for 4 points"),  # the Floor's values on the light
    ([ao(FLOOR, np.ones(8), "constant")], f"{FLOOR}: 8 constant values, not one element"),
    ([ao(FLOOR, np.ones(3), "uniform")], f"{FLOOR}: 3 uniform values for 4 faces"),
    ([ao(FLOOR, np.ones(15), "faceVarying")], f"{FLOOR}: 15 faceVarying values for 16 face-vertex corners"),
    ([ao(FLOOR, np.ones(9), "varying")], ""),
    ([ao(FLOOR, np.ones(9), element_size=2)], f"{FLOOR}: 9 vertex values of elementSize 2 for 9 points"),
    ([ao(FLOOR, np.ones(18), element_size=2)], ""),
    ([ao(FLOOR, np.ones(9), "vertez")], f"{FLOOR}.primvars:bake:ao: interpolation 'vertez'"),
    ([ao(FLOOR, np.ones(9), element_size=0)], f"{FLOOR}.primvars:bake:ao: elementSize 0"),
    ([ao(FLOOR, np.ones(9), element_size=True)], f"{FLOOR}.primvars:bake:ao: elementSize True"),
    ([Primvar(FLOOR, "bake:ao", np.float32(1.0), "float", "constant")],
     f"{FLOOR}.primvars:bake:ao: its values are not an array"),
    (["bake:ao"], "outputs[0] is a str, not an output record"),
    # Prims the Scene holds no topology for: only a constant's size is known.
    ([ao("/World/Looks/White", np.ones(5))], ""),
    ([ao("/World/Looks/White", np.ones(2), "constant")], "/World/Looks/White: 2 constant values, not one element"),
    # A prim a step defines with its own points: measured against them, as the bake layer will be.
    ([Attribute("/World/Probes", "points", np.zeros((6, 3), np.float32), "point3f[]"),
      ao("/World/Probes", np.ones(5))], "/World/Probes: 5 vertex values for 6 points"),
])
def test_a_result_is_measured_against_the_scene(outputs, why, cornell, cornell_ao):
    assert misfit(with_outputs(cornell_ao, *outputs), cornell) == why


def test_the_real_result_fits_and_its_products_must_be_declared(cornell, cornell_ao):
    provides = (AmbientOcclusionProduct,)
    assert misfit(cornell_ao, cornell, provides=provides) == ""
    ao_product = cornell_ao.products[AmbientOcclusionProduct]
    foreign = dataclasses.replace(cornell_ao, products={SkyVisibilityProduct: ao_product})
    assert misfit(foreign, cornell, provides=provides) == \
        "product 'SkyVisibilityProduct' is not one the processor provides"
    assert misfit(foreign, cornell) == ""  # no declared products given: not checked
    listed = dataclasses.replace(cornell_ao, outputs=dict(enumerate(cornell_ao.outputs)))
    assert misfit(listed, cornell) == "its outputs are a dict, not a list"


def test_face_varying_values_are_at_least_the_corners_the_triangles_reach(cornell, cornell_ao):
    """With a face left out (a hole), the Scene knows only the corners its triangles reach."""
    floor = cornell.prim_paths.index(FLOOR)
    last_face = (cornell.tri_prim == floor) & (cornell.tri_face == 3)
    keep = ~last_face
    holed = dataclasses.replace(cornell, **{name: getattr(cornell, name)[keep] for name in (
        "tri_vertices", "tri_normals", "tri_areas", "tri_albedo", "tri_emission", "tri_prim", "tri_face",
        "tri_instance", "tri_double_sided", "tri_corner")})
    assert misfit(with_outputs(cornell_ao, ao(FLOOR, np.ones(16), "faceVarying")), holed) == ""
    assert misfit(with_outputs(cornell_ao, ao(FLOOR, np.ones(11), "faceVarying")), holed) == \
        f"{FLOOR}: 11 faceVarying values for at least 12 face-vertex corners"


def test_a_sealed_entry_that_does_not_fit_is_recomputed_and_rewritten(cornell, tmp_path):
    """The Floor's 9 values moved onto the LightQuad's 4 points, the manifest resealed: the hash vouches
    for it, the scene does not."""
    cache_dir = tmp_path / "cache"
    assert bake(cache_dir, cornell) == "run"
    manifest, _ = manifest_and_arrays(cache_dir, cornell)
    content = json.loads(manifest.read_text())
    records = content["tree"]["fields"]["outputs"]
    prims = [record["fields"]["prim"] for record in records]
    records[prims.index(LIGHT)]["fields"]["values"] = records[prims.index(FLOOR)]["fields"]["values"]
    reseal(manifest, content)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        steps = Pipeline.build(["ambient_occlusion"], AO_FAST, runtime=Runtime(Tracer.from_scene),
                               cache_dir=cache_dir).run(cornell)
    assert [str(w.message) for w in caught if issubclass(w.category, CacheWarning)] == [
        f"usdbake cache: {manifest}: does not fit the scene ({LIGHT}: 9 vertex values for 4 points); recomputing"]
    assert (steps[0].action, steps[0].reason) == ("run", "cache entry unusable (see the warning); recomputed")
    light = next(record for record in steps[0].result.outputs if record.prim == LIGHT)
    assert len(light.values) == 4
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        assert bake(cache_dir, cornell) == "cached"


# ---------------------------------------------------------------------------
# A cache that cannot be written: one warning for the run, which completes


class FullDisk(io.FileIO):
    """A file on a device that fills up after ``room`` bytes: the write that passes it raises ``errno``."""

    room = 100  # less than any entry: the first store fails partway
    errno = errno.ENOSPC

    def write(self, data) -> int:
        if self.tell() + len(data) > self.room:
            raise OSError(self.errno, os.strerror(self.errno))
        return super().write(data)


def failing_open(code: int):
    """``open`` for core.cache whose files fill up with error ``code`` (reads are the real ones)."""
    def fake(path, mode="r", *args, **kwargs):
        if "w" not in mode:
            return open(path, mode, *args, **kwargs)
        handle = FullDisk(path, "w")
        handle.errno = code
        return handle
    return fake


TWO_STEPS = (["ambient_occlusion", "progressive_mesh"], AO_FAST)


def unwritable_warning(folder, strerror: str) -> str:
    return f"usdbake cache: cannot write in {folder} ({strerror}); results of this run are not cached"


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EFBIG, errno.EROFS, errno.EACCES])
def test_a_write_that_fails_warns_once_and_the_run_completes(code, cornell, tmp_path, monkeypatch):
    reference = Pipeline.build(*TWO_STEPS, runtime=Runtime(Tracer.from_scene)).run(cornell)
    cache_dir = tmp_path / "cache"
    monkeypatch.setattr(core.cache, "open", failing_open(code), raising=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pipeline = Pipeline.build(*TWO_STEPS, runtime=Runtime(Tracer.from_scene), cache_dir=cache_dir)
        steps = pipeline.run(cornell)
    assert [str(w.message) for w in caught if issubclass(w.category, CacheWarning)] == [
        unwritable_warning(cache_dir, os.strerror(code))]  # two steps, one warning
    assert actions(steps) == {"ambient_occlusion": "run", "progressive_mesh": "run"}
    for a, b in zip(reference, steps):
        assert_same(a.result, b.result, a.name)
    assert list(cache_dir.iterdir()) == []  # the partial file is gone, nothing else was written
    monkeypatch.undo()
    assert actions(Pipeline.build(*TWO_STEPS, runtime=Runtime(Tracer.from_scene),
                                  cache_dir=cache_dir).run(cornell)) == {
        "ambient_occlusion": "run", "progressive_mesh": "run"}  # a later run writes again
    assert actions(Pipeline.build(*TWO_STEPS, runtime=Runtime(Tracer.from_scene),
                                  cache_dir=cache_dir).run(cornell)) == {
        "ambient_occlusion": "cached", "progressive_mesh": "cached"}


def test_a_cache_folder_that_cannot_be_made_warns_once(cornell, tmp_path):
    """No fault injected: the folder's parent is a file, so making it fails as it does on a real disk."""
    (tmp_path / "file").write_text("not a folder")
    cache_dir = tmp_path / "file" / "cache"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        steps = Pipeline.build(*TWO_STEPS, runtime=Runtime(Tracer.from_scene), cache_dir=cache_dir).run(cornell)
    assert [str(w.message) for w in caught if issubclass(w.category, CacheWarning)] == [
        unwritable_warning(cache_dir, os.strerror(errno.ENOTDIR))]
    assert set(actions(steps).values()) == {"run"} and all(step.result.outputs for step in steps)


@pytest.fixture
def read_only(tmp_path):
    folder = tmp_path / "shared"
    folder.mkdir()
    locker = ReadOnly(folder)
    yield locker
    locker.unlock()  # else pytest cannot remove tmp_path


def test_a_read_only_cache_folder_is_still_read_and_warns_once(cornell, read_only):
    """A shared cache others fill and we may only read: its entries are served, a new one warns once."""
    folder = read_only.folder
    Pipeline.build(["ambient_occlusion"], AO_FAST, runtime=Runtime(Tracer.from_scene),
                   cache_dir=folder).run(cornell)  # filled while writable
    strerror = read_only.lock()
    before = sorted(folder.iterdir())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        steps = Pipeline.build(*TWO_STEPS, runtime=Runtime(Tracer.from_scene), cache_dir=folder).run(cornell)
    assert [str(w.message) for w in caught if issubclass(w.category, CacheWarning)] == [
        unwritable_warning(folder, strerror)]
    assert actions(steps) == {"ambient_occlusion": "cached", "progressive_mesh": "run"}
    assert steps[1].result.outputs
    assert sorted(folder.iterdir()) == before


# ---------------------------------------------------------------------------
# Concurrent writers


def sample_result(*, readonly: bool = True) -> Result:
    """A Result with one of each kind of value the cache stores."""
    rng = np.random.default_rng(7)  # fixed seed: any values do
    frozen = rng.random(1000).astype(np.float32)
    frozen.flags.writeable = not readonly
    return Result(
        products={AmbientOcclusionProduct: AmbientOcclusionProduct(frozen),
                  InstanceOcclusionProduct: InstanceOcclusionProduct({None: frozen, 2.5: frozen[:3].copy()}, {})},
        outputs=[Primvar("/World/a", "bake:ao", frozen, "float", "vertex"),
                 Attribute("/World/a", "bake:indices", Block(), "int[]"),
                 Attribute("/World/a", "bake:scale", np.float32(0.5), "float", time=1.0),
                 Attribute("/World/a", "bake:range", (float("-inf"), float("nan")), "float2"),
                 File("operator.bin", bytes(range(256)) * 4)],
        stats={"rays": 1.5e7, "seconds": np.float64(0.25)},
        messages=["a message", ""])


def test_concurrent_writers_never_leave_a_reader_a_broken_entry(tmp_path, no_cache_warnings):
    # Writable arrays only: a pickle to the worker processes may not keep the read-only flag.
    name, key, expected = "ambient_occlusion", "c" * 32, sample_result(readonly=False)
    cache = ResultCache(tmp_path)

    def store_many():
        for _ in range(20):
            cache.store(name, key, expected)
    loaded, failures = [], []
    done = threading.Event()

    def read():
        while not done.is_set():
            try:
                result = cache.load(name, key)
            except Exception as error:  # noqa: BLE001 - a warning (made an error) or a crash: both fail the test
                failures.append(error)
                return
            if result is not None:
                loaded.append(result)

    reader = threading.Thread(target=read)
    reader.start()
    try:
        spawn = multiprocessing.get_context("spawn")
        with spawn.Pool(2) as pool:
            pool.map(ResultCache, [None, None], chunksize=1)  # workers import usdbake first, so all writers overlap
            # 40 stores in two chunks of 20, one per worker; the workers import only usdbake.
            processes = pool.starmap_async(cache.store, [(name, key, expected)] * 40, chunksize=20)
            threads = [threading.Thread(target=store_many) for _ in range(2)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            processes.get(timeout=120)
        time.sleep(0.05)  # let the reader see the final entry too
    finally:
        done.set()
        reader.join()

    assert failures == []
    assert loaded, "the reader never saw an entry"
    for result in loaded[:: max(1, len(loaded) // 20)] + loaded[-1:]:
        assert_same(result, expected)
    assert [path.name for path in tmp_path.iterdir() if path.name.endswith(".tmp")] == []
    assert_same(cache.load(name, key), expected)


def test_old_arrays_files_of_an_entry_are_pruned(tmp_path, no_cache_warnings):
    cache, name, key = ResultCache(tmp_path), "ambient_occlusion", "d" * 32
    old, recent = tmp_path / f"{name}-{key}.{'0' * 16}.npz", tmp_path / f"{name}-{key}.{'1' * 16}.npz"
    for path in (old, recent):
        path.write_bytes(b"an earlier run's arrays")
    long_ago = time.time() - 2 * STALE_SECONDS
    os.utime(old, (long_ago, long_ago))
    cache.store(name, key, sample_result())
    assert not old.exists() and recent.exists()  # a recent one may be a concurrent writer's
    assert_same(cache.load(name, key), sample_result())


# ---------------------------------------------------------------------------
# What cannot be stored fails loudly


@dataclasses.dataclass(frozen=True)
class Unregistered:
    """A product type in no usdbake module and no registered processor's."""

    values: np.ndarray


@pytest.mark.parametrize("result, where", [
    (Result(products={AmbientOcclusionProduct: AmbientOcclusionProduct(np.array([object()], dtype=object))}),
     r"^products\.AmbientOcclusionProduct\.point_ao: cannot store an array of dtype object"),
    (Result(messages=[lambda: None]), r"^messages\[0\]: cannot store builtins\.function"),
    (Result(outputs=[Attribute("/World/a", "bake:x", io.BytesIO(), "asset")]),
     r"^outputs\[0\]\.value: cannot store _io\.BytesIO"),
    (Result(stats={"rays": np.ma.masked_array([1.0])}), r"^stats\.rays: cannot store numpy\.ma"),
    (Result(products={Unregistered: Unregistered(np.zeros(1))}), r"^products key .*not from usdbake"),
])
def test_a_value_the_cache_cannot_store_fails_loudly(result, where, tmp_path):
    with pytest.raises(TypeError, match=where):
        ResultCache(tmp_path).store("ambient_occlusion", "e" * 32, result)
    assert list(tmp_path.iterdir()) == []


@dataclasses.dataclass(frozen=True)
class UnstorableProduct:
    values: np.ndarray


class Unstorable(Processor):
    """A registered processor (so its module's types may be stored) whose product holds an object array."""

    name = "unstorable"
    provides = (UnstorableProduct,)

    def run(self, ctx):
        return Result(products={UnstorableProduct: UnstorableProduct(np.array([print], dtype=object))})


def test_the_runner_surfaces_an_unstorable_result(tmp_path):
    core.registry.registry()
    core.registry.register(Unstorable)
    try:
        with pytest.raises(TypeError, match="products.UnstorableProduct.values: cannot store an array of dtype object"):
            Pipeline.build(["unstorable"], runtime=Runtime(Tracer.from_scene),
                           cache_dir=tmp_path).run(fakes.make_scene())
    finally:
        core.registry.unregister("unstorable")


# ---------------------------------------------------------------------------
# Plain data


def test_plain_values_round_trip_with_their_types():
    frozen = np.arange(12, dtype=np.int16).reshape(3, 4)
    frozen.flags.writeable = False
    value = {
        "none": None, "bools": (True, False, np.bool_(True)), "ints": [0, -1, 2**70, np.int64(-5), np.uint8(250)],
        "floats": [0.1, -0.0, float("inf"), float("-inf"), float("nan"), np.float32(1.5), np.float16(0.25)],
        "text": "naïve ✓", "bytes": b"\x00\xff", "empty": b"",
        "arrays": [frozen, np.zeros((0, 3), np.float32), np.arange(10.0)[::3], np.array(["2024-06-21T12"],
                   "datetime64[us]"), np.array(3.5), np.array([1 + 2j])],
        7: "int key", 2.5: "float key", None: "None key", ("a", 1): "tuple key", SkyVisibilityProduct: "type key",
        "dataclass": Block(), "scene": fakes.make_scene(),
    }
    tree, arrays = plain_data.encode(value)
    json.dumps(tree, allow_nan=False)  # plain JSON
    back = plain_data.decode(tree, arrays)
    assert_same(back, value)
    assert back["arrays"][0].flags.writeable is False and back["arrays"][2].flags.writeable is True
    assert back["scene"].fingerprint(tuple(FACETS)) == value["scene"].fingerprint(tuple(FACETS))


def test_an_array_two_fields_share_is_stored_once_and_shared_again():
    shared = np.arange(5.0)
    tree, arrays = plain_data.encode([shared, shared])
    assert len(arrays) == 1
    first, second = plain_data.decode(tree, arrays)
    assert first is second


@pytest.mark.parametrize("name", [
    "os:system",  # not usdbake
    "usdbake.core.scene:Scene.fingerprint",  # not a type
    "usdbake.core.scene:np.ndarray",  # a type, not a dataclass of that module
    "usdbake.core.scene:Scene.__init__.__globals__",
    "usdbake.core.products:RefinedScene.<locals>",
])
def test_only_dataclass_types_of_trusted_modules_are_resolved(name):
    with pytest.raises(ValueError):
        plain_data.resolve(name)
    assert plain_data.resolve("usdbake.core.products:RefinedScene") is RefinedScene


PLUGIN = '''
from usdbake.core import Processor, Result


class Shared(Processor):
    name = "shared_plugin"

    def run(self, ctx):
        return Result()
'''


def test_code_fingerprint_is_the_same_wherever_the_code_is_installed(tmp_path):
    """Farm workers install usdbake (and plugins) in different folders; they must share cache entries."""
    import subprocess
    import sys

    keys = []
    for folder in ("install_a", "somewhere/else/install_b"):
        root = tmp_path / folder
        (root / "shared_plugin").mkdir(parents=True)
        (root / "shared_plugin" / "__init__.py").write_text(PLUGIN)
        code = ("from usdbake.core.cache import code_fingerprint; from shared_plugin import Shared; "
                "print(code_fingerprint(Shared))")
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))}
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        keys.append(done.stdout.strip())
    assert len(keys[0]) == 64 and keys[0] == keys[1]
    (tmp_path / "install_a" / "shared_plugin" / "__init__.py").write_text(PLUGIN + "\n# edited\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "install_a")}
    edited = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert edited.stdout.strip() != keys[0]  # the code itself still counts


def test_an_edit_to_the_ray_cores_cpp_changes_the_code_fingerprint(tmp_path, monkeypatch):
    """The ray core's C++ is read by kernels.traversal, not imported: its NATIVE_SOURCES count as code, so an edited
    traversal never serves a bake cached before the edit."""
    from usdbake.core.cache import code_fingerprint
    from usdbake.kernels import traversal
    from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion

    header = tmp_path / "trace.h"
    header.write_text("// the traversal\n")
    monkeypatch.setattr(traversal, "NATIVE_SOURCES", (*traversal.NATIVE_SOURCES, header))
    before = code_fingerprint(AmbientOcclusion)
    assert before == code_fingerprint(AmbientOcclusion)
    header.write_text("// the traversal, edited\n")
    assert code_fingerprint(AmbientOcclusion) != before
