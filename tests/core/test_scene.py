"""core.scene on its own: read-only, contiguous arrays after construction (inputs stay the caller's),
the defaults ``__post_init__`` fills in, the derived properties (bounds, diagonal, up vector, per-prim
point slices) against numpy written out here, the fingerprint's facets (each sees the fields it names
and only those, every name resolves), ``Lights.dome_texture`` from each kind of source, and
``Instances.targets`` / ``is_native``.

Fingerprints that tell dtype and shape apart are tested in tests/core/test_pipeline.py.
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest
from patch_scenes import box_parts, make_scene
from usdbake.core import scene as scene_module
from usdbake.core.scene import FACETS, Instances, Lights, Scene


def box_scene(**overrides):
    scene = make_scene(box_parts(size=2.0))
    return replace(scene, **overrides) if overrides else scene


def test_arrays_are_read_only_copies_and_contiguous():
    points = np.asfortranarray(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32))
    base = make_scene([(points, np.array([[0, 1, 2]]))])
    strided = np.zeros((3, 6), np.float32)[:, ::2]  # a non-contiguous view
    scene = replace(base, points=strided)
    assert scene.points.flags.c_contiguous and not scene.points.flags.writeable
    for f in fields(scene):
        value = getattr(scene, f.name)
        if isinstance(value, np.ndarray):
            assert not value.flags.writeable, f.name
            with pytest.raises(ValueError):
                value[...] = 0
    # A non-contiguous input is copied: the caller's view stays writable and apart from the scene's.
    strided[0, 0] = 5.0
    assert scene.points[0, 0] == 0.0


def test_post_init_fills_per_triangle_and_per_prim_defaults():
    scene = box_scene()
    t = scene.num_triangles
    assert t == 12 and scene.num_points == 24
    np.testing.assert_array_equal(scene.tri_corner, np.full((t, 3), -1))
    assert scene.tri_corner.dtype == np.int32
    np.testing.assert_array_equal(scene.tri_transmittance, np.zeros(t))
    assert scene.tri_transmittance.dtype == np.float32
    assert scene.prim_instance_roots == ((),) * 6
    given = replace(scene, prim_instance_roots=(("/A",),) + ((),) * 5)
    assert given.prim_instance_roots[0] == ("/A",)  # not overwritten when given


def test_bounds_diagonal_up_vector_and_prim_points():
    scene = box_scene()
    lo, hi = scene.bounds
    np.testing.assert_array_equal(lo, [0, 0, 0])
    np.testing.assert_array_equal(hi, [2, 2, 2])
    assert scene.diagonal == pytest.approx(2 * np.sqrt(3), rel=1e-15)
    moved = replace(scene, points=scene.points + np.float32([1e4, -3, 0.5]))
    assert moved.diagonal == pytest.approx(2 * np.sqrt(3), rel=1e-15)  # 2.0 apart is exact at 1e4 in float32
    empty = replace(scene, points=np.zeros((0, 3), np.float32))
    assert empty.diagonal == 0.0 and [b.tolist() for b in empty.bounds] == [[0, 0, 0], [0, 0, 0]]
    np.testing.assert_array_equal(scene.up_vector, [0, 1, 0])
    np.testing.assert_array_equal(replace(scene, up_axis="Z").up_vector, [0, 0, 1])
    assert scene.up_vector.dtype == np.float32
    for prim in range(6):
        part = scene.prim_points(prim)
        assert (part.start, part.stop) == (4 * prim, 4 * prim + 4)
        np.testing.assert_array_equal(scene.point_prim[part], prim)


def test_every_facet_names_fields_that_exist():
    scene = box_scene()
    for facet, names in FACETS.items():
        for name in names:
            scene_module._lookup(scene, name)  # AttributeError if a name drifted
    assert scene_module._lookup(scene, "lights.light_kind") is scene.lights.light_kind
    with pytest.raises(KeyError):
        scene.fingerprint(("no_such_facet",))


@pytest.mark.parametrize("facet, change", [
    ("geometry", dict(points=lambda s: s.points + np.float32(0.5))),
    ("geometry", dict(up_axis=lambda s: "Z")),
    ("geometry", dict(origin=lambda s: np.array([0.0, 0.0, 1e-9]))),
    ("materials", dict(tri_albedo=lambda s: s.tri_albedo * np.float32(0.5))),
    ("materials", dict(prim_surface=lambda s: ("/Looks/M",) + s.prim_surface[1:])),
    ("lights", dict(lights=lambda s: Lights(light_paths=("/Sun",), light_kind=np.zeros(1, np.int32),
                                            light_radiance=np.ones((1, 3), np.float32),
                                            light_position=np.zeros((1, 3), np.float32),
                                            light_direction=np.float32([[0, -1, 0]]),
                                            light_size=np.float32([[0.53, 0]])))),
    ("instancers", dict(instances=lambda s: Instances(instance_prototype=np.zeros(1, np.int32)))),
    ("time", dict(time_code=lambda s: 24.0)),
])
def test_a_change_moves_its_own_facet_and_no_other(facet, change):
    scene = box_scene()
    changed = replace(scene, **{name: make(scene) for name, make in change.items()})
    for other in FACETS:
        same = scene.fingerprint((other,)) == changed.fingerprint((other,))
        assert same == (other != facet), f"{other} after a change of {facet}"
    # A fingerprint of several facets is the hash of them in order: order matters, repeats are not dropped.
    assert scene.fingerprint(("geometry", "materials")) != scene.fingerprint(("materials", "geometry"))
    assert len(scene.fingerprint(())) == 64


def test_fingerprint_is_a_function_of_content_not_identity():
    a, b = box_scene(), box_scene()
    assert a.points is not b.points
    assert a.fingerprint(tuple(FACETS)) == b.fingerprint(tuple(FACETS))
    # -0.0 and 0.0 compare equal but differ in bytes: the fingerprint sees the bytes.
    negative_zero = replace(a, origin=np.array([-0.0, 0.0, 0.0]))
    assert np.array_equal(negative_zero.origin, a.origin)
    assert negative_zero.fingerprint(("geometry",)) != a.fingerprint(("geometry",))


def test_dome_texture_from_none_an_array_or_a_callable():
    assert Lights().dome_texture.shape == (0, 0, 3) and not Lights().dome_texture.flags.writeable
    pixels = np.arange(2 * 4 * 3, dtype=np.float64).reshape(2, 4, 3)
    from_array = Lights(dome_source=pixels).dome_texture
    assert from_array.dtype == np.float32 and not from_array.flags.writeable
    np.testing.assert_array_equal(from_array, pixels)
    calls = []

    def read():
        calls.append(1)
        return pixels

    lights = Lights(dome_source=read)
    assert calls == []  # nothing read at construction
    np.testing.assert_array_equal(lights.dome_texture, pixels)
    assert calls == [1]
    assert len(lights) == 0 and len(Lights(light_paths=("/A", "/B"))) == 2
    np.testing.assert_array_equal(Lights().dome_to_local, np.eye(3))


def test_instances_targets_and_native_flags():
    instances = Instances(instancer_paths=("/I", "/N"), prototype_paths=("/I/P0", "/I/P1"),
                          instance_prototype=np.array([0, 1, 1], np.int32), instancer_native=np.array([False, True]))
    assert len(instances) == 3
    assert instances.targets(1) == ("/I/P1",)  # no prototype_targets: the prototype's own path
    assert not instances.is_native(0) and instances.is_native(1)
    native = replace(instances, prototype_targets=(("/I/P0",), ("/Proto/a", "/Proto/b")))
    assert native.targets(1) == ("/Proto/a", "/Proto/b")
    # Flags or targets of another length than the paths are ignored, not indexed out of range.
    assert not replace(instances, instancer_native=np.array([True])).is_native(0)
    assert replace(instances, prototype_targets=(("/x",),)).targets(0) == ("/I/P0",)


def test_scene_is_frozen():
    scene = box_scene()
    with pytest.raises(AttributeError):
        scene.points = np.zeros((0, 3), np.float32)
    assert isinstance(scene, Scene)
