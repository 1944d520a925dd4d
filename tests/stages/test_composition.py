"""stages.composition: composition faults as data (CompositionFault), their order, the one line
check_composition makes of them (a StageError, or warnings under allow_missing), a Pcp text that cannot be
read, and quiet_composition_warnings, which drops USD's own print of them and nothing else.

Missing sublayers, references and payloads through the command and the hook are
tests/stages/test_composition_faults.py's; this file calls the module's functions on small stages."""

from pathlib import Path

import pytest
from pxr import Sdf, Tf, Usd

from usdbake.core.errors import StageError
from usdbake.stages.composition import (CompositionFault, _fault, check_composition, composition_faults,
                                        quiet_composition_warnings)


def write(path: Path, text: str) -> Path:
    path.write_text("#usda 1.0\n" + text)
    return path


def faulty_root(folder: Path) -> tuple[Path, Path]:
    """root.usda sublayers mid.usda (which sublayers a missing gone_b.usda) and a missing gone_a.usda, and
    references a missing gone_ref.usda on /World/Chair; returns (root, mid)."""
    mid = write(folder / "mid.usda", "(\n    subLayers = [@gone_b.usda@]\n)\n")
    root = write(folder / "root.usda", """(
    subLayers = [@mid.usda@, @gone_a.usda@]
)

def Xform "World"
{
    def Xform "Chair" (
        prepend references = @gone_ref.usda@
    )
    {
    }
}
""")
    return root, mid


# --- the fault record -------------------------------------------------------------------------


@pytest.mark.parametrize("fault, description", [
    (CompositionFault("/s/root.usda", "sublayer", "gone.usda", "", "not found"), "sublayer gone.usda not found"),
    (CompositionFault("/s/root.usda", "reference", "chair.usda", "/World/Chair", "has no defaultPrim"),
     "reference chair.usda on /World/Chair has no defaultPrim"),
    (CompositionFault("/s/root.usda", "payload", "set.usda</Nope>", "/World/Set", "not found"),
     "payload set.usda</Nope> on /World/Set not found"),
    (CompositionFault("/s/root.usda", "", "", "", "whatever Pcp said, whole"), "whatever Pcp said, whole"),
], ids=["sublayer", "reference", "payload-target", "unread-text"])
def test_a_fault_reads_as_one_line_naming_the_asking_layer(fault, description):
    assert fault.description == description
    assert fault.message() == f"/s/root.usda: {description}"


def test_a_text_that_matches_no_known_form_is_kept_whole_on_the_root_layer():
    text = "Some future Pcp message @x.usda@ nobody parses"
    assert _fault(text, "/s/root.usda") == CompositionFault("/s/root.usda", "", "", "", text)


# --- faults of a stage ------------------------------------------------------------------------


def test_faults_are_sorted_sublayers_first_and_the_root_layers_before_others(tmp_path):
    root, mid = faulty_root(tmp_path)
    stage = Usd.Stage.Open(str(root))
    root_id, mid_id = stage.GetRootLayer().identifier, Sdf.Layer.Find(str(mid)).identifier
    assert composition_faults(stage) == [
        CompositionFault(root_id, "sublayer", "gone_a.usda", "", "not found"),
        CompositionFault(mid_id, "sublayer", "gone_b.usda", "", "not found"),
        CompositionFault(root_id, "reference", "gone_ref.usda", "/World/Chair", "not found"),
    ]


def test_an_unreadable_sublayer_is_a_fault_with_the_parsers_reason(tmp_path):
    broken = write(tmp_path / "broken.usda", 'def Xform "X" {\n')
    root = write(tmp_path / "root.usda", "(\n    subLayers = [@broken.usda@]\n)\n")
    [fault] = composition_faults(Usd.Stage.Open(str(root)))
    assert (fault.arc, fault.prim) == ("sublayer", "")
    assert fault.asset in ("broken.usda", str(broken))  # as authored, or anchored to the asking layer
    assert fault.problem.startswith("cannot be read (") and fault.problem.endswith(")")
    assert fault.problem != "cannot be read ()" and "\n" not in fault.problem


def test_a_reference_inside_a_variant_names_the_variant_selection(tmp_path):
    root = write(tmp_path / "root.usda", """
def Xform "World"
{
    def Xform "Chair" (
        variants = {
            string look = "red"
        }
        prepend variantSets = "look"
    )
    {
        variantSet "look" = {
            "red" (
                prepend references = @gone_red.usda@
            ) {
            }
        }
    }
}
""")
    [fault] = composition_faults(Usd.Stage.Open(str(root)))
    assert (fault.arc, fault.asset, fault.problem) == ("reference", "gone_red.usda", "not found")
    assert fault.prim == "/World/Chair{look=red}"


# --- check_composition ------------------------------------------------------------------------


def test_a_sound_stage_passes_with_no_warnings(tmp_path):
    write(tmp_path / "set.usda", '(\n    defaultPrim = "Set"\n)\ndef Xform "Set"\n{\n}\n')
    root = write(tmp_path / "root.usda", "def Xform \"World\" (\n    prepend references = @set.usda@\n)\n{\n}\n")
    stage = Usd.Stage.Open(str(root))
    assert check_composition(stage) == []
    assert check_composition(stage, allow_missing=True) == []


def test_one_fault_is_a_stage_error_naming_the_layer_and_the_remedy(tmp_path):
    root = write(tmp_path / "root.usda", "(\n    subLayers = [@gone.usda@]\n)\n")
    stage = Usd.Stage.Open(str(root))
    with pytest.raises(StageError) as raised:
        check_composition(stage)
    root_id = stage.GetRootLayer().identifier
    assert (raised.value.prim, raised.value.attribute) == (root_id, "")
    assert str(raised.value) == f"{root_id}: sublayer gone.usda not found; --allow-missing bakes without it"


def test_several_faults_name_the_first_and_count_the_rest(tmp_path):
    root, _ = faulty_root(tmp_path)
    stage = Usd.Stage.Open(str(root))
    root_id = stage.GetRootLayer().identifier
    with pytest.raises(StageError) as raised:
        check_composition(stage)
    assert str(raised.value) == (f"{root_id}: sublayer gone_a.usda not found (and 2 more); --allow-missing bakes "
                                 f"without them")


def test_allow_missing_turns_each_fault_into_a_warning_line_in_order(tmp_path):
    root, _ = faulty_root(tmp_path)
    stage = Usd.Stage.Open(str(root))
    faults = composition_faults(stage)
    assert check_composition(stage, allow_missing=True) == [f"{fault.message()}; baked without it"
                                                            for fault in faults]
    assert len(faults) == 3


# --- USD's own print of the faults ------------------------------------------------------------


@pytest.mark.skipif(not hasattr(Tf, "DiagnosticTrap"), reason="an older usd-core prints the warnings")
def test_quiet_composition_warnings_drops_only_the_composition_report(tmp_path, capfd):
    root = write(tmp_path / "root.usda", "(\n    subLayers = [@gone_quiet.usda@]\n)\n")
    capfd.readouterr()
    with quiet_composition_warnings():
        stage = Usd.Stage.Open(str(root))
        Tf.Warn("a diagnostic of another kind")
    err = capfd.readouterr().err
    assert "a diagnostic of another kind" in err  # passes through
    assert "gone_quiet.usda" not in err
    assert len(composition_faults(stage)) == 1  # the fault is still there to report

    Usd.Stage.Open(str(root))  # outside the block USD prints it: the check above is not vacuous
    assert "Could not load sublayer @gone_quiet.usda@" in capfd.readouterr().err
