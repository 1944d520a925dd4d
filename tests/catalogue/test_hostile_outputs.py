"""Hostile cases around a bake's own files (issue 27, item 1 and the output parts of item 8).

A bake layer's provenance is text anyone can edit. A re-bake removes a file only when it is in the
output's folder, carries the name usdbake gives sidecars and still has the SHA-256 the old layer
recorded for it; everything else a layer names stays. Every case also checks that the input is
byte-identical afterwards.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
from pxr import Sdf, Vt

from usdbake.cli.main import main

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
FIELDS = ["-p", "displacement_fields", "--set", "displacement_fields.positional_samples=64",
          "--set", "displacement_fields.direction_map_size=8"]


def digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.fixture
def baked(tmp_path):
    """instanced_props baked with displacement fields into out/p.usdc (three PNG sidecars)."""
    source = tmp_path / "props.usda"
    source.write_bytes((SAMPLES / "instanced_props.usda").read_bytes())
    out = tmp_path / "out" / "p.usdc"
    assert main(["bake", str(source), "-o", str(out), *FIELDS]) == 0
    return source, out


def provenance(out: Path) -> dict:
    return dict(dict(Sdf.Layer.OpenAsAnonymous(str(out)).customLayerData)["usdbake"])


def edit_provenance(out: Path, **changes) -> None:
    layer = Sdf.Layer.FindOrOpen(str(out))
    data = dict(layer.customLayerData)
    data["usdbake"] = {**dict(data["usdbake"]), **changes}
    layer.customLayerData = data
    layer.Save()


def rebake(source: Path, out: Path, *extra) -> int:
    before = digest(source)
    code = main(["bake", str(source), "-o", str(out), *FIELDS, "--force", *extra])
    assert digest(source) == before
    return code


def test_rebake_leaves_files_outside_the_folder_that_the_layer_lists(baked, tmp_path):
    """The issue's repro: '../victim.txt' and an absolute path added to the sidecars, with digests."""
    source, out = baked
    victim, absolute = tmp_path / "victim.txt", tmp_path / "elsewhere" / "mine.txt"
    absolute.parent.mkdir()
    victim.write_text("mine")
    absolute.write_text("also mine")
    old = provenance(out)
    edit_provenance(out, sidecars=Vt.StringArray([*old["sidecars"], "../victim.txt", str(absolute)]),
                    sidecarDigests=Vt.StringArray([*old["sidecarDigests"], digest(victim), digest(absolute)]))
    assert rebake(source, out, "--set", "displacement_fields.positional_samples=81") == 0
    assert victim.read_text() == "mine" and absolute.read_text() == "also mine"
    removed = [name for name in old["sidecars"] if not (out.parent / name).exists()]
    assert sorted(removed) == sorted(old["sidecars"])  # its own old fields, which the new bake replaced, went


def test_rebake_leaves_a_user_file_in_the_folder_named_otherwise(baked):
    source, out = baked
    notes = out.parent / "notes.png"
    notes.write_bytes(b"user data")
    old = provenance(out)
    edit_provenance(out, sidecars=Vt.StringArray([*old["sidecars"], "./notes.png"]),
                    sidecarDigests=Vt.StringArray([*old["sidecarDigests"], digest(notes)]))
    assert rebake(source, out, "--set", "displacement_fields.positional_samples=81") == 0
    assert notes.read_bytes() == b"user data"


def test_rebake_keeps_a_sidecar_the_user_changed_or_replaced_by_a_link(baked, tmp_path):
    source, out = baked
    names = list(provenance(out)["sidecars"])
    edited, linked = out.parent / names[0], out.parent / names[1]
    edited.write_bytes(b"painted over by hand")
    target = tmp_path / "precious.png"
    target.write_bytes(linked.read_bytes())  # the same bytes: the digest matches through the link
    linked.unlink()
    linked.symlink_to(target)
    assert rebake(source, out, "--set", "displacement_fields.positional_samples=81") == 0
    assert edited.read_bytes() == b"painted over by hand"
    assert linked.is_symlink() and target.exists()
    assert not (out.parent / names[2]).exists()  # the untouched one was the bake's and went


def test_rebake_of_a_layer_without_digests_removes_nothing(baked, tmp_path):
    """An input texture the old output names, and its listed sidecars: no digests, nothing removed."""
    source, out = baked
    texture = tmp_path / "albedo.png"
    texture.write_bytes(b"an input texture")
    old = provenance(out)
    layer = Sdf.Layer.FindOrOpen(str(out))
    data = dict(layer.customLayerData)
    stripped = {key: value for key, value in dict(data["usdbake"]).items() if key != "sidecarDigests"}
    data["usdbake"] = {**stripped, "sidecars": Vt.StringArray([*old["sidecars"], "../albedo.png"])}
    layer.customLayerData = data
    layer.Save()
    assert rebake(source, out, "--set", "displacement_fields.positional_samples=81") == 0
    assert texture.read_bytes() == b"an input texture"
    assert all((out.parent / name).exists() for name in old["sidecars"])


def test_rebake_with_the_same_content_keeps_its_files(baked):
    source, out = baked
    before = {name: digest(out.parent / name) for name in provenance(out)["sidecars"]}
    assert rebake(source, out) == 0
    assert {name: digest(out.parent / name) for name in provenance(out)["sidecars"]} == before


@pytest.mark.skipif(os.name != "posix", reason="symlinks")
def test_rebake_does_not_follow_a_sidecar_link_out_of_the_folder(baked, tmp_path):
    """A sidecar name that is a link to a file elsewhere, with that file's digest recorded: the
    link is not followed, so the file it points at stays."""
    source, out = baked
    names = list(provenance(out)["sidecars"])
    outside = tmp_path / "outside.png"
    outside.write_bytes(b"outside")
    (out.parent / names[0]).unlink()
    (out.parent / names[0]).symlink_to(outside)
    old = provenance(out)
    digests = list(old["sidecarDigests"])
    digests[0] = digest(outside)
    edit_provenance(out, sidecarDigests=Vt.StringArray(digests))
    assert rebake(source, out, "--set", "displacement_fields.positional_samples=81") == 0
    assert outside.read_bytes() == b"outside"


# ---------------------------------------------------------------------------
# A previous output that is corrupt, and an output that cannot be written whole


@pytest.mark.parametrize("provenance_text", ['string usdbake = "x"', "dictionary usdbake = {\n int sidecars = 5\n }"],
                         ids=["provenance-a-string", "sidecars-a-number"])
def test_a_corrupt_previous_output_is_one_line_or_replaced(tmp_path, capsys, provenance_text):
    """Provenance that is not usdbake's dictionary: the file is not ours (exit 2, untouched); a
    dictionary with a nonsense sidecar list is ours and is replaced, removing nothing."""
    source = tmp_path / "box.usda"
    source.write_bytes((SAMPLES / "cornell_box.usda").read_bytes())
    out = tmp_path / "out.usda"
    out.write_text(f'#usda 1.0\n(\n    customLayerData = {{\n        {provenance_text}\n    }}\n    subLayers = [@box.usda@]\n)\n')
    before = out.read_bytes()
    capsys.readouterr()
    code = main(["bake", str(source), "-o", str(out), "--set", "ambient_occlusion.samples=16"])
    err = capsys.readouterr().err
    if provenance_text.startswith("string"):
        assert code == 2 and out.read_bytes() == before
        assert err.strip().splitlines()[-1] == (f"usdbake: error: {out}: exists and was not written by usdbake; "
                                                f"refusing to replace it (remove it or choose another -o)")
    else:
        assert code == 0, err
        assert provenance(out)["processors"]["ambient_occlusion"]["action"] in ("run", "cached")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.usda", "out.usda"]


LIMITED_BAKE = """
import resource, sys
from usdbake.cli.main import main
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, resource.RLIM_INFINITY))  # writes past it fail: EFBIG
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("extra, limit", [
    (["--set", "ambient_occlusion.samples=16"], 1024),
    ([*FIELDS, "--set", "displacement_fields.positional_samples=256", "--set",
      "displacement_fields.direction_map_size=16"], 2048),  # the PNGs are written first, each > 2 KB
], ids=["layer-too-large", "texture-too-large"])
def test_a_full_disk_is_one_line_exit_1_and_the_previous_output_stays(tmp_path, extra, limit):
    """A real short write (RLIMIT_FSIZE, as `ulimit -f` or a full disk gives): OpenImageIO reports a
    short PNG write only in its error text, USD raises; both are one line, exit 1."""
    import subprocess
    import sys

    source = tmp_path / "props.usda"
    source.write_bytes((SAMPLES / "instanced_props.usda").read_bytes())
    out = tmp_path / "out" / "p.usda"
    cache = tmp_path / "cache"
    assert main(["bake", str(source), "-o", str(out), "--cache", str(cache), *FIELDS]) == 0  # kernels compiled
    before = {p.name: digest(p) for p in out.parent.iterdir()}
    done = subprocess.run([sys.executable, "-c", LIMITED_BAKE.format(limit=limit), "bake", str(source), "-o",
                           str(out), "--force", "--cache", str(cache), *extra], capture_output=True, text=True,
                          timeout=600)
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 1, done.stderr[-2000:]
    assert last.startswith(f"usdbake: error: {out}: could not be written (") and \
        last.endswith("); the previous output is unchanged"), last
    assert "Traceback" not in done.stderr
    assert {p.name: digest(p) for p in out.parent.iterdir()} == before
