"""Every processor on every sample gives the results recorded before the renovation, bit for bit."""

from __future__ import annotations

import json

import pytest
from result_fingerprints import RECORD, SAMPLES, fingerprints
from stress.stage_builders_stress import FAST_PARAMS

RECORDED = json.loads(RECORD.read_text())


@pytest.mark.parametrize("case", sorted(RECORDED))
def test_results_match_the_recorded_fingerprints(case):
    sample, name = case.split("/")
    now = fingerprints(SAMPLES / f"{sample}.usda", name, FAST_PARAMS[name])
    before = RECORDED[case]
    assert now["action"] == before["action"]
    changed = sorted(key for key in before.get("records", {}) if now["records"].get(key) != before["records"][key])
    assert now.get("records", {}).keys() == before.get("records", {}).keys()
    assert not changed, f"{len(changed)} of {len(before['records'])} records changed, e.g. {changed[:3]}"


def test_every_sample_and_processor_is_recorded():
    assert {case.split("/")[1] for case in RECORDED} == set(FAST_PARAMS)
    assert {case.split("/")[0] for case in RECORDED} == {path.stem for path in SAMPLES.glob("*.usda")}
