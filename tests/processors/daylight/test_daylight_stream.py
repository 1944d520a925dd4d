"""The daylight stream (formats/daylight_stream.py, processors/daylight/daylight_stream.py): what the browser
gets relights as the library does, within the 8-bit codes of the indirect coefficients, and a stream cut at
any section still relights every face."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from daylight_boxes import box_with_skylight
from tolerances import FLOAT32_ACCUMULATED, FLOAT32_STORAGE, INDIRECT_CODE_RELIGHT
from usdbake.formats.daylight_stream import decode_daylight_stream, encode_daylight_stream, received_source, section_ends
from usdbake.kernels.sky import tregenza_patches
from usdbake.kernels.tracer import Tracer
from usdbake.preview.stream_client import StreamedDaylight
from usdbake.processors.daylight.daylight import DaylightRelighter, sun_table
from usdbake.processors.daylight.daylight_stream import indirect_code_error, stream_coefficients
from usdbake.processors.daylight.interreflection import compute_interreflection
from usdbake.processors.daylight.sky_visibility import compute_sky_visibility

SITE = dict(latitude=41.98, longitude=2.82, timezone=1.0)
CASES = [("2026-06-21T12:00", "preetham"), ("2026-12-21T10:30", "preetham"), ("2026-03-20T16:00", "perez"),
         ("2026-09-01T08:15", "overcast"), ("2026-06-21T19:30", "uniform")]


@pytest.fixture(scope="module")
def baked():
    scene = box_with_skylight(0.5, n=8)
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=tregenza_patches(), samples=16, adaptive=False)
    inter, _ = compute_interreflection(tracer, scene, product, bounces=3, gather_rays=32, patches=48)
    table = sun_table(tracer, product, latitude=SITE["latitude"], declination_step=12.0, hour_step=15.0,
                      samples=4)
    relighter = DaylightRelighter(product, table, **SITE, interreflection=inter)
    data = stream_coefficients(scene, product, inter, table, site=dict(SITE, north=0.0))
    return relighter, inter, encode_daylight_stream(data, packet_faces=64)


def test_the_whole_stream_relights_as_the_library_within_the_indirect_codes(baked):
    relighter, inter, stream = baked
    client = StreamedDaylight(decode_daylight_stream(stream))
    error = indirect_code_error(inter.sky_indirect)
    assert 0 < error <= 1 / 255 + 1e-6  # near the top, d(c^2)/dc = 2c: one step is 2/255, half of it rounds
    # The library relighting the coefficients as the wire carries them: D through its 8-bit codes, decoded
    # here by hand, D = s (c / 255)^2
    scale = inter.sky_indirect.max(axis=2, keepdims=True)
    share = inter.sky_indirect / np.where(scale > 0, scale, 1)
    coded = (np.round(np.sqrt(share) * 255) / 255) ** 2 * scale
    wire = DaylightRelighter(relighter.product, relighter.table, **SITE,
                             interreflection=replace(inter, sky_indirect=coded.astype(np.float32)))
    for when, sky in CASES:
        want = relighter.at(np.datetime64(when), sky=sky)
        got = client.in_bake_order(client.at(when, sky=sky))
        np.testing.assert_allclose(got, wire.at(np.datetime64(when), sky=sky), rtol=FLOAT32_ACCUMULATED,
                                   atol=FLOAT32_STORAGE * np.abs(want).max())  # the rest of the wire is exact
        lit = want > 0.01 * want.max()
        ratio = (np.abs(got - want) / np.maximum(want, 1e-30))[lit]
        assert ratio.max() <= INDIRECT_CODE_RELIGHT, (when, sky, ratio.max(), np.percentile(ratio, 99))


def test_a_cut_stream_relights_every_face_from_its_ancestors(baked):
    relighter, _, stream = baked
    ends = [end for _, end in section_ends(stream)]
    whole = StreamedDaylight(decode_daylight_stream(stream))
    full = whole.at("2026-06-21T12:00", sky="overcast")
    previous = None
    for end in ends[1:]:  # after the sky and geometry sections: every FACES section boundary
        prefix = decode_daylight_stream(stream[:end])
        client = StreamedDaylight(prefix)
        values = client.at("2026-06-21T12:00", sky="overcast")
        assert client.shown.all() == (prefix.received > 0)
        assert np.isfinite(values).all()
        if prefix.received:  # received faces are exact; the rest copy an earlier face's light
            np.testing.assert_array_equal(values[:prefix.received], full[:prefix.received])
            source = received_source(prefix.parent, prefix.received)
            np.testing.assert_array_equal(source[:prefix.received], np.arange(prefix.received))
            assert (source < prefix.received).all()
        previous = values
    np.testing.assert_array_equal(previous, full)
    torn = decode_daylight_stream(stream[:ends[-1] - 5])  # a torn last section is dropped, not misread
    assert torn.received < len(torn.parent)


def test_the_scenes_other_triangles_travel_for_context():
    """instanced_props: the floor is the one receiver; its PointInstancer's crates, vases and benches cast
    the shadows on it, so they travel as context triangles. Receivers and context together are the scene's
    whole surface (its triangle areas, summed independently)."""
    from pxr import Usd

    from repo_paths import SAMPLES
    from stress.stage_builders_stress import fast_params
    from usdbake.core.pipeline import Pipeline
    from usdbake.core.records import File
    from usdbake.core.runtime import Runtime
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(Usd.Stage.Open(str(SAMPLES / "instanced_props.usda")))
    steps = Pipeline.build(["daylight_stream"], fast_params("daylight_stream"),
                           runtime=Runtime(Tracer.from_scene)).run(scene)
    stream = next(r.data for s in steps if s.name == "daylight_stream" for r in s.result.outputs if isinstance(r, File))
    prefix = decode_daylight_stream(stream)
    assert [p["path"] for p in prefix.header["prims"]] == ["/World/Floor"] and len(prefix.context) > 1000

    def area(corners):
        corners = corners.astype(np.float64)
        return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()

    receivers = area(prefix.points[prefix.corners.astype(np.int64)])
    assert receivers + area(prefix.context) == pytest.approx(float(scene.tri_areas.sum()), rel=1e-5)
