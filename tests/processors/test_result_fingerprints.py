"""Every processor on every sample gives the results recorded before the renovation, bit for bit."""

from __future__ import annotations

import json

import pytest
from result_fingerprints import RECORD, SAMPLES, fingerprints
from stress.stage_builders_stress import fast_params
from usdbake.core import registry

RECORDED = json.loads(RECORD.read_text())


@pytest.mark.parametrize("case", sorted(RECORDED))
def test_results_match_the_recorded_fingerprints(case):
    sample, name = case.split("/")
    now = fingerprints(SAMPLES / f"{sample}.usda", name, fast_params(name))
    before = RECORDED[case]
    assert now["action"] == before["action"]
    changed = sorted(key for key in before.get("records", {}) if now["records"].get(key) != before["records"][key])
    assert now.get("records", {}).keys() == before.get("records", {}).keys()
    assert not changed, f"{len(changed)} of {len(before['records'])} records changed, e.g. {changed[:3]}"


def test_recorded_cases_are_every_sample_for_built_in_processors():
    """Each recorded processor is recorded on every sample; a processor added since has no record yet
    (``python tests/result_fingerprints.py NAME`` pins its results)."""
    recorded = {case.split("/")[1] for case in RECORDED}
    assert recorded <= set(registry.builtin())
    samples = {path.stem for path in SAMPLES.glob("*.usda")}
    assert {case for case in RECORDED} == {f"{sample}/{name}" for sample in samples for name in recorded}
