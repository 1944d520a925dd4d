"""Content hashes of every processor's output records on every sample stage.

The renovation moved every module of the library; its promise was that no
result changes by a single bit. ``tests/data/result_fingerprints.json`` was
recorded by this module before the move (``python tests/result_fingerprints.py``)
and ``test_result_fingerprints.py`` recomputes it. A deliberate change of
results re-records only the cases it changes (``python tests/result_fingerprints.py
light_probes cornell_box/radiosity``) in a commit of its own that says why and
what was measured.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
SAMPLES = HERE.parent / "samples"
RECORD = HERE / "data" / "result_fingerprints.json"


def _digest_value(digest, value) -> None:
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.tobytes())
    elif isinstance(value, (bytes, bytearray)):
        digest.update(bytes(value))
    elif isinstance(value, (list, tuple)):
        digest.update(f"seq{len(value)}".encode())
        for item in value:
            _digest_value(digest, item)
    else:
        digest.update(repr(value).encode())


LATER_FIELDS = {"custom": False, "references": ()}
"""Record fields added after the fingerprints were first recorded (Attribute.custom, Prim.references), with
their defaults: hashed only where a record sets them, so records that do not keep their digests."""


def record_digest(record) -> tuple[str, str]:
    """(a readable key naming the record, sha256 of every field of it)."""
    digest = hashlib.sha256(type(record).__name__.encode())
    for f in dataclasses.fields(record):
        if f.name in LATER_FIELDS and getattr(record, f.name) == LATER_FIELDS[f.name]:
            continue
        digest.update(f.name.encode())
        _digest_value(digest, getattr(record, f.name))
    where = getattr(record, "prim", None) or getattr(record, "path", "")
    name = getattr(record, "name", "")
    time = getattr(record, "time", None)
    key = f"{type(record).__name__} {where} {name}" + (f" @{time}" if time is not None else "")
    return key, digest.hexdigest()[:24]


def processor_step(sample: Path, name: str, params: dict, device: str = "cpu"):
    """The run step of processor ``name`` (with its dependencies) on one sample, on ``device``."""
    from usdbake.stages.extract import extract_scene
    from usdbake.core.pipeline import Pipeline
    from usdbake.core.runtime import Runtime
    from usdbake.kernels.tracer import Tracer
    from pxr import Usd

    scene = extract_scene(Usd.Stage.Open(str(sample)))
    steps = Pipeline.build([name], params, runtime=Runtime(Tracer.from_scene, device=device)).run(scene)
    return next(s for s in steps if s.name == name)


def fingerprints(sample: Path, name: str, params: dict) -> dict:
    """{'action': run|skip, 'records': {key: digest}} for one processor (with its dependencies) on one sample."""
    step = processor_step(sample, name, params)
    records: dict[str, str] = {}
    if step.action == "skip":
        return {"action": "skip"}
    for record in step.result.outputs:
        key, value = record_digest(record)
        n = 1
        while key in records:  # several records of one kind on one prim (textures of a field)
            n += 1
            key = f"{key} #{n}"
        records[key] = value
    return {"action": step.action, "records": records}


def compute(samples=None, processors=None) -> dict:
    from stress.stage_builders_stress import fast_params
    from usdbake.core import registry

    table = {}
    for sample in sorted(samples or SAMPLES.glob("*.usda")):
        for name in sorted(processors or registry.builtin()):
            table[f"{sample.stem}/{name}"] = fingerprints(sample, name, fast_params(name))
    return table


def main(argv: list[str]) -> None:
    """``python tests/result_fingerprints.py`` records every case; ``... NAME [SAMPLE/NAME ...]`` re-records
    only those (a processor on every sample, or one case) and keeps the rest as recorded."""
    sys.path.insert(0, str(HERE))
    if not argv:
        table = compute()
    else:
        table = json.loads(RECORD.read_text())
        for case in argv:
            sample, _, name = case.rpartition("/")
            samples = [SAMPLES / f"{sample}.usda"] if sample else None
            table.update(compute(samples, [name]))
    RECORD.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
    print(f"wrote {RECORD}")


if __name__ == "__main__":
    main(sys.argv[1:])
