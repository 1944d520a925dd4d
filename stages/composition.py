"""Composition faults: sublayers, references and payloads a stage asks for but could not compose.

OpenUSD composes around a missing or unreadable asset: the stage opens, the
arc contributes nothing, and a bake would silently leave that geometry out.
``Usd.Stage.GetCompositionErrors()`` lists the failed arcs; its Python
bindings expose only the error type and the site, so the asset path, the
introducing layer and the prim are read from the error's text (Pcp's
descriptions, pinned by tests/stages/test_composition_faults.py). A text that
does not match is still reported, whole, so no fault passes silently.

Faults are data (``CompositionFault``); ``check_composition`` turns them into
one line each: a StageError for the first, or warnings under ``allow_missing``.
"""

from __future__ import annotations

import re
from contextlib import contextmanager
from dataclasses import dataclass

from pxr import Pcp, Tf, Usd

from ..core.errors import StageError

FAULT_TYPES = (Pcp.ErrorType_InvalidSublayerPath, Pcp.ErrorType_InvalidAssetPath, Pcp.ErrorType_UnresolvedPrimPath)
"""Pcp error types that drop an authored asset (or the prim it names) from the composed stage."""

_SUBLAYER = re.compile(r"Could not load sublayer @(?P<asset>[^@]*)@ of layer @(?P<layer>[^@]*)@"
                       r"(?: -- (?P<reason>.*?))?; skipping\.$")
_ASSET = re.compile(r"Could not open asset @(?P<asset>[^@]*)@ for (?P<arc>\w+) introduced by "
                    r"@(?P<layer>[^@]*)@<(?P<prim>[^>]*)>(?: -- (?P<reason>.*?))?\.?$")
_PRIM_PATH = re.compile(r"Unresolved (?P<arc>\w+) prim path @(?P<asset>[^@]*)@<(?P<target>[^>]*)> introduced by "
                        r"@(?P<layer>[^@]*)@<(?P<prim>[^>]*)>")


@dataclass(frozen=True)
class CompositionFault:
    """One arc that contributes nothing to the composed stage."""

    layer: str
    """Identifier of the layer that asks for the asset."""
    arc: str
    """'sublayer', 'reference' or 'payload' ('' when Pcp's text could not be read: ``problem`` holds it)."""
    asset: str
    """The asset path as Pcp reports it (as authored, or anchored to the asking layer), with the
    target prim (``asset</Prim>``) when the asset opened but lacks that prim."""
    prim: str
    """Prim path the reference or payload is authored on (with any variant selection); '' for sublayers."""
    problem: str
    """'not found', 'cannot be read (<parser message>)' or 'has no defaultPrim'."""

    @property
    def description(self) -> str:
        """The fault without the asking layer: arc, asset path, prim and problem."""
        if not self.arc:
            return self.problem
        on = f" on {self.prim}" if self.prim else ""
        return f"{self.arc} {self.asset}{on} {self.problem}"

    def message(self) -> str:
        """One line: the asking layer, then the fault."""
        return f"{self.layer}: {self.description}"


def composition_faults(stage: Usd.Stage) -> list[CompositionFault]:
    """Every missing or unreadable sublayer, reference and payload of ``stage``.

    Sorted (Pcp's order varies from run to run): sublayers first, the root layer's before
    others', then by asking layer, prim and asset. Payloads count only where they are loaded
    (an unloaded payload is not part of the stage).
    """
    root = stage.GetRootLayer().identifier
    faults: set[CompositionFault] = set()
    for error in stage.GetCompositionErrors():
        if error.errorType in FAULT_TYPES:
            # Whitespace is collapsed: a parser message inside Pcp's text may end in a newline.
            try:
                faults.add(_fault(" ".join(str(error).split()), root))
            except UnicodeDecodeError:  # it quotes an asset's bytes that are not UTF-8
                from .inputs import undecodable_asset

                what = undecodable_asset(stage) or "an asset cannot be read (USD's message is not UTF-8 text)"
                faults.add(_fault(f"{what}, asked for at {error.rootSite.path}", root))
    return sorted(faults, key=lambda f: (f.arc != "sublayer", f.layer != root, f.layer, f.prim, f.asset, f.problem))


@contextmanager
def quiet_composition_warnings():
    """Drop the warnings USD prints for composition errors while a stage opens inside this block
    (``composition_faults`` reports each as one line); every other diagnostic passes through."""
    if not hasattr(Tf, "DiagnosticTrap"):  # an older usd-core: nothing to trap with, USD prints them
        yield
        return
    with Tf.DiagnosticTrap() as trap:
        try:
            yield
        finally:
            trap.EraseMatching(lambda diagnostic: diagnostic.sourceFunction.endswith("UsdStage::_ReportErrors"))


def check_composition(stage: Usd.Stage, *, allow_missing: bool = False) -> list[str]:
    """Raise StageError naming the first composition fault (and how many more there are);
    with ``allow_missing``, return one warning line per fault instead."""
    faults = composition_faults(stage)
    if faults and not allow_missing:
        more = f" (and {len(faults) - 1} more)" if len(faults) > 1 else ""
        hint = f"; --allow-missing bakes without {'them' if more else 'it'}"
        raise StageError(faults[0].layer, "", f"{faults[0].description}{more}{hint}")
    return [f"{fault.message()}; baked without it" for fault in faults]


def _fault(text: str, root_layer: str) -> CompositionFault:
    if match := _SUBLAYER.match(text):
        return CompositionFault(match["layer"], "sublayer", match["asset"], "", _problem(match["reason"]))
    if match := _ASSET.match(text):
        return CompositionFault(match["layer"], match["arc"], match["asset"], match["prim"], _problem(match["reason"]))
    if match := _PRIM_PATH.match(text):
        if match["target"] == "defaultPrim":
            return CompositionFault(match["layer"], match["arc"], match["asset"], match["prim"], "has no defaultPrim")
        return CompositionFault(match["layer"], match["arc"], f"{match['asset']}<{match['target']}>", match["prim"],
                                "not found")
    return CompositionFault(root_layer, "", "", "", text)


def _problem(reason: str | None) -> str:
    return f"cannot be read ({reason.strip()})" if reason else "not found"
