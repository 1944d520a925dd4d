"""kernels.trace_instances on Scenes built here (no pxr): which instances ``instanced_arrays`` traces
two-level and which it leaves flat (the "auto" saving threshold, singular transforms, geometry that is
not its prototype's under the transform, runs that are not consecutive, a different triangle count),
the per-instance arrays it hands the ray core (first face, mirroring, a to-world map that takes the
reference triangles onto each instance's), and closest hits through the two-level scene against the
same triangles traced flat.

PointInstancer stages read through USD are traced two-level in tests/kernels/test_ray_core.py.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from patch_scenes import make_scene, quad
from tolerances import FLOAT32_ACCUMULATED, FLOAT32_STORAGE
from usdbake.core.scene import Instances
from usdbake.kernels import trace_instances as ti
from usdbake.kernels.tracer import Tracer

TETRA = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float64) * 0.4
TETRA_TRIS = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def rotation_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])  # row-vector convention: x' = x @ R


def transform(linear=np.eye(3), translate=(0, 0, 0)):
    """(4, 4) row-vector prototype-to-world matrix."""
    m = np.eye(4)
    m[:3, :3], m[3, :3] = linear, translate
    return m


def instanced_scene(transforms, *, perturb=None, drop_triangle=None, floor=True):
    """A floor (static) and one tetrahedron per transform, instances 0, 1, ... of prototype 0, each
    instance's triangles consecutive in prototype order (reversed winding when mirrored, as extraction
    writes them). ``perturb``: an instance whose first vertex is moved off the transform; ``drop_triangle``:
    an instance listed with one triangle fewer."""
    parts, tri_instance = [], []
    if floor:
        parts.append(quad([-1, -1, 0], [8, 0, 0], [0, 8, 0]))
        tri_instance += [-1, -1]
    for k, m in enumerate(transforms):
        points = TETRA @ m[:3, :3] + m[3, :3]
        if k == perturb:
            points[0] += 0.05
        tris = TETRA_TRIS[:, ::-1] if np.linalg.det(m[:3, :3]) < 0 else TETRA_TRIS
        if k == drop_triangle:
            tris = tris[:-1]
        parts.append((points, tris))
        tri_instance += [k] * len(tris)
    scene = make_scene(parts)
    instances = Instances(instancer_paths=("/World/Scatter",), prototype_paths=("/World/Scatter/Tetra",),
                          instance_instancer=np.zeros(len(transforms), np.int32),
                          instance_prototype=np.zeros(len(transforms), np.int32),
                          instance_transforms=np.asarray(transforms, np.float64).reshape(-1, 4, 4))
    return replace(scene, tri_instance=np.asarray(tri_instance, np.int32), instances=instances)


FIVE = [transform(translate=(0.5, 0.5, 0.1)), transform(translate=(2, 0.5, 0.1)),
        transform(rotation_z(0.7), (3.5, 1, 0.1)), transform(np.diag([1.5, 0.5, 2.0]), (0.5, 3, 0.1)),
        transform(np.diag([-1.0, 1.0, 1.0]), (3, 3, 0.1))]  # off the floor: translated, rotated, scaled, mirrored


def flat_and_two_level_hits(scene, arrays):
    rng = np.random.default_rng(17)  # fixed seed
    origins = np.column_stack([rng.uniform(-0.5, 5, 3000), rng.uniform(-0.5, 5, 3000), rng.uniform(0.2, 3, 3000)])
    # Rays from above aimed at random points of random instanced triangles (the floor is met around them).
    corners = scene.points.astype(np.float64)[scene.tri_vertices[np.asarray(scene.tri_instance) >= 0]]
    pick = corners[rng.integers(0, len(corners), 3000)]
    weights = rng.dirichlet(np.ones(3), 3000)
    directions = np.einsum("nk,nkj->nj", weights, pick) - origins
    flat = Tracer(scene.points, scene.tri_vertices).closest_hit(origins, directions)
    two = Tracer(scene.points, scene.tri_vertices, arrays=arrays).closest_hit(origins, directions)
    return flat, two


def test_bad_choice_raises_and_never_or_no_instances_trace_flat():
    scene = instanced_scene(FIVE)
    with pytest.raises(ValueError, match="instancing 'sometimes'"):
        ti.instanced_arrays(scene, "sometimes")
    assert ti.instanced_arrays(scene, "never") is None
    assert ti.instanced_arrays(replace(scene, instances=Instances()), "always") is None
    no_marks = replace(scene, tri_instance=np.full(scene.num_triangles, -1, np.int32))
    assert ti.instanced_arrays(no_marks, "always") is None


def test_two_level_arrays_describe_each_instance_and_trace_like_the_flat_scene():
    scene = instanced_scene(FIVE)
    arrays = ti.instanced_arrays(scene, "auto")  # 5 x 4 instanced triangles >= 4 x 4 of the prototype
    assert arrays is not None and arrays.top_root >= 0
    # Instances 0..4, then the static floor as one identity instance whose lanes are scene triangles.
    np.testing.assert_array_equal(arrays.instance_face, [2, 6, 10, 14, 18, 0])
    np.testing.assert_array_equal(arrays.instance_mirrored, [0, 0, 0, 0, 1, 0])
    np.testing.assert_allclose(arrays.instance_to_world[5], np.eye(3, 4), atol=0)
    # Each to_world (x_world = A x + b) takes the first instance's corners onto instance k's (re-wound if mirrored).
    corners = scene.points.astype(np.float64)[scene.tri_vertices]
    reference = corners[2:6]
    for k in range(5):
        m = arrays.instance_to_world[k].astype(np.float64)
        moved = reference @ m[:, :3].T + m[:, 3]
        if arrays.instance_mirrored[k]:
            moved = moved[:, ::-1]
        np.testing.assert_allclose(moved, corners[2 + 4 * k:6 + 4 * k], atol=FLOAT32_STORAGE * 4)  # coords up to ~4
        square = np.vstack([m, [0, 0, 0, 1]])
        np.testing.assert_allclose(np.vstack([arrays.instance_to_object[k], [0, 0, 0, 1]]) @ square, np.eye(4),
                                   atol=FLOAT32_STORAGE * 10)
    flat, two = flat_and_two_level_hits(scene, arrays)
    hit_instance = np.asarray(scene.tri_instance)[flat.hit_triangle[flat.hit_triangle >= 0]]
    assert (hit_instance >= 0).sum() > 1500 and (hit_instance == 4).sum() > 200  # the mirrored one is met too
    np.testing.assert_array_equal(two.hit_triangle, flat.hit_triangle)
    np.testing.assert_array_equal(two.hit_front, flat.hit_front)
    hit = flat.hit_triangle >= 0
    np.testing.assert_allclose(two.hit_t[hit], flat.hit_t[hit], rtol=FLOAT32_ACCUMULATED, atol=FLOAT32_ACCUMULATED)
    np.testing.assert_allclose(two.hit_uv[hit], flat.hit_uv[hit], atol=FLOAT32_ACCUMULATED * 10)


def test_auto_needs_the_stated_saving_and_always_does_not():
    assert ti.AUTO_MIN_SAVING == 4.0
    three = instanced_scene(FIVE[:3])  # 12 instanced triangles < 4 x 4
    assert ti.instanced_arrays(three, "auto") is None
    arrays = ti.instanced_arrays(three, "always")
    assert arrays is not None and len(arrays.instance_face) == 4
    four = instanced_scene(FIVE[:4])  # 16, not below 16: worth it
    assert ti.instanced_arrays(four, "auto") is not None


@pytest.mark.parametrize("case", ["perturbed", "singular", "fewer_triangles"])
def test_instances_that_do_not_match_their_prototype_are_traced_flat(case):
    transforms = list(FIVE)
    kwargs = {}
    if case == "perturbed":
        kwargs["perturb"] = 2  # its first vertex 0.05 off: far above MATCH_TOLERANCE x diagonal
    elif case == "singular":
        transforms[2] = transform(np.diag([1.0, 1.0, 0.0]), (3.5, 1, 0.1))  # flattened to the plane z = 0.1
    else:
        kwargs["drop_triangle"] = 2
    scene = instanced_scene(transforms, **kwargs)
    arrays = ti.instanced_arrays(scene, "always")
    own = np.flatnonzero((np.asarray(scene.tri_instance) == 2) & (scene.tri_areas > 0))  # flattened: 2 of 4 left
    # Instance 2 is not among the two-level instances; its triangles are lanes of the static tree (the
    # prototype's tree numbers its lanes 0..3, the static one by scene triangle, 10 and above here).
    assert 10 not in arrays.instance_face[:-1].tolist() and len(arrays.instance_face) == 5
    assert set(own.tolist()) <= set(arrays.packet_triangle.ravel().tolist())
    if case != "singular":  # a zero-volume tetrahedron's faces are met only edge-on
        flat, two = flat_and_two_level_hits(scene, arrays)
        assert np.isin(flat.hit_triangle, own).sum() > 200
        np.testing.assert_array_equal(two.hit_triangle, flat.hit_triangle)


def test_instance_runs_need_consecutive_triangles():
    tri_instance = np.array([-1, 0, 0, 1, 1, 0, -1, 2])  # instance 0 split in two, instance 3 absent
    assert ti._instance_runs(tri_instance, 4) == [(0, 0), (3, 2), (7, 1), (0, 0)]
    assert ti._instance_runs(np.full(3, -1), 2) == [(0, 0), (0, 0)]
    assert ti._instance_runs(np.array([1, 1, 1, 0]), 2) == [(3, 1), (0, 3)]
    # A split instance in a scene is traced flat, the others two-level.
    scene = instanced_scene(FIVE)
    marks = np.asarray(scene.tri_instance).copy()
    marks[[6, 7]], marks[[10, 11]] = 2, 1  # instances 1 and 2 interleaved: neither run is consecutive
    arrays = ti.instanced_arrays(replace(scene, tri_instance=marks), "always")
    np.testing.assert_array_equal(arrays.instance_face, [2, 14, 18, 0])


def test_matches_within_tolerance_and_with_reversed_winding():
    reference = TETRA[TETRA_TRIS]
    to_world = np.hstack([np.diag([-1.0, 1.0, 1.0]), [[1.0], [2.0], [3.0]]])
    ours = (reference @ to_world[:, :3].T + to_world[:, 3])[:, ::-1]
    assert ti._matches(reference, ours, to_world, True, 1e-9)
    assert not ti._matches(reference, ours, to_world, False, 1e-9)  # the winding is part of the geometry
    nudged = ours.copy()
    nudged[0, 0, 0] += 1e-3
    assert ti._matches(reference, nudged, to_world, True, 2e-3)
    assert not ti._matches(reference, nudged, to_world, True, 5e-4)
    assert ti._matches(np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), to_world, False, 0.0)  # nothing to compare
