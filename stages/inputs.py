"""What a user points usdbake at, checked before any compute: the stage to open and the output path.

One line naming the problem for each (a UsageError, exit 2 on the command line).
"""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

from pxr import Sdf, Tf, Usd

from ..core.errors import UsageError
from .bake_layer import LAYER_SUFFIXES, bake_source
from .provenance import is_bake_layer
from .sidecars import TEMP_TAG


def open_source(path: str):
    """Open the stage to bake: the input, or the source of a usdbake output."""
    if not Path(path).exists():
        raise UsageError(f"{path}: no such file")
    try:
        source = bake_source(path)
        stage = Usd.Stage.Open(source)
    except Tf.ErrorException as error:
        raise UsageError(f"{path}: cannot be read as USD ({usd_reason(error, path)})") from None
    if stage is None:
        raise UsageError(f"{path}: cannot be read as USD")
    return source, stage


def usd_reason(error: Exception, path: str | Path | None = None) -> str:
    """The human part of a Tf error: the text after the last ' : ', without the quotes.

    A parser error quotes the line it stopped at; when that line holds bytes that are not UTF-8, the
    message cannot be turned into text at all (``str(error)`` raises UnicodeDecodeError), so the
    reason is found in ``path`` instead: the line and the bytes, printed with backslash escapes.
    """
    try:
        text = str(error)
    except UnicodeDecodeError:
        where = not_utf8(path) if path is not None and _is_text_layer(path) else ""
        return f"{where}; a .usda layer is UTF-8 text" if where else "USD's message about it is not UTF-8 text"
    # Whitespace is collapsed first: a parser message can end in a newline inside its quotes.
    return " ".join(text.split()).rsplit(" : ", 1)[-1].strip("'\" ")


def undecodable_asset(stage: Usd.Stage) -> str:
    """``<asset> cannot be read (line N: byte 0x.. is not UTF-8, in: <the line>; ...)`` for the first text
    layer the stage's layers ask for (sublayer, reference, payload) holding bytes that are not UTF-8; '' if none.

    Pcp's message about such an asset quotes the parser's, bytes and all, and cannot be turned into
    text (``str(error)`` raises UnicodeDecodeError): this says which asset it was instead.
    """
    for layer in stage.GetUsedLayers():
        for asset in layer.GetCompositionAssetDependencies():
            path = layer.ComputeAbsolutePath(asset)
            where = not_utf8(path) if _is_text_layer(path) else ""
            if where:
                return f"{asset} cannot be read ({where}; a .usda layer is UTF-8 text)"
    return ""


def _is_text_layer(path: str | Path) -> bool:
    """Whether ``path`` is a .usda text layer (by its first bytes, whatever its extension)."""
    try:
        with open(path, "rb") as handle:
            return handle.read(5) == b"#usda"
    except OSError:
        return False


def not_utf8(path: str | Path) -> str:
    """Where a file first holds bytes that are not UTF-8: ``line 3: byte 0xe9 is not UTF-8, in: <the line>``
    (the line printed with backslash escapes, so it always prints); '' when it is UTF-8 or unreadable."""
    try:
        data = Path(path).read_bytes()
        data.decode("utf-8")
    except OSError:
        return ""
    except UnicodeDecodeError as error:
        return undecodable(error)
    return ""


def undecodable(error: UnicodeDecodeError, *, width: int = 80) -> str:
    """``line N: byte 0x.. is not UTF-8, in: <the line>`` for the bytes a UTF-8 decode stopped at."""
    data = bytes(error.object)
    start = data.rfind(b"\n", 0, error.start) + 1
    end = data.find(b"\n", error.start)
    line = data[start:end if end >= 0 else len(data)].decode("utf-8", errors="backslashreplace").strip()
    shown = line if len(line) <= width else line[:width - 3] + "..."
    bad = " ".join(f"0x{byte:02x}" for byte in data[error.start:error.end])
    number = data.count(b"\n", 0, error.start) + 1
    return f"line {number}: byte {bad} is not UTF-8, in: {shown}"


def check_output(out_path: str, source_path: str | None = None, used_layers=()) -> Path:
    """Refuse an output path usdbake cannot or must not write, before any compute; the resolved path.

    Checks the extension, that it is not a folder, that its folder can be created and written, that
    it is neither the input nor any layer the input uses, and that an existing file there is a
    usdbake output (a bake replaces only its own outputs).
    """
    path = Path(out_path)
    accepted = f"{', '.join(LAYER_SUFFIXES[:-1])} or {LAYER_SUFFIXES[-1]}"
    if path.is_dir():
        raise UsageError(f"{out_path}: is a folder; give a layer file name ending in {accepted}")
    suffix = path.suffix.lower()
    if suffix == ".usdz":
        raise UsageError(f"{out_path}: usdbake does not write .usdz packages (the bake layer sublayers its "
                         f"input and names its sidecar files); write {accepted}")
    if suffix not in LAYER_SUFFIXES:
        found = f"unsupported extension '{path.suffix}'" if path.suffix else "no extension"
        raise UsageError(f"{out_path}: {found}; the output must be a {accepted} layer")
    out = path.resolve()
    if source_path is not None and out == Path(source_path).resolve():
        raise UsageError(f"{out_path}: refusing to overwrite the input layer; choose another -o")
    for layer in used_layers:
        real = getattr(layer, "realPath", "") or ""
        if real and Path(real).resolve() == out:
            raise UsageError(f"{out_path}: refusing to overwrite {Path(real).name}, a layer the input uses; "
                             f"choose another -o")
    check_writable_folder(out.parent, what=out_path)
    if out.exists():
        try:
            existing = Sdf.Layer.OpenAsAnonymous(str(out), metadataOnly=True)
        except Tf.ErrorException:
            existing = None
        if existing is None or not is_bake_layer(existing):
            raise UsageError(f"{out_path}: exists and was not written by usdbake; refusing to replace it "
                             f"(remove it or choose another -o)")
    return out


def check_writable_folder(folder: Path, *, what: str) -> None:
    """Refuse a folder that cannot be created or written: its nearest existing ancestor must be a
    folder we can create files in (tried, not guessed from permission bits: root, read-only mounts)."""
    ancestor = Path(folder).resolve()
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise UsageError(f"{what}: {ancestor} is a file, not a folder")
    try:
        handle, probe = tempfile.mkstemp(prefix=f".usdbake{TEMP_TAG}{os.getpid()}-", dir=ancestor)
    except OSError as error:
        raise UsageError(f"{what}: cannot write in {ancestor} ({error.strerror})") from None
    os.close(handle)
    os.unlink(probe)


def check_device(device, *, option: str = "--device") -> None:
    """'cpu', or a CUDA device Warp can see ('cuda', 'cuda:N'); Warp is asked only for a CUDA one."""
    if device == "cpu":
        return
    if not isinstance(device, str) or not re.fullmatch(r"cuda(:\d+)?", device):
        raise UsageError(f"{_given(option, device)}: expected cpu or cuda:N")
    import warp as wp

    try:
        wp.get_device(device)
    except (ValueError, RuntimeError):
        available = ", ".join(str(d.alias) for d in wp.get_devices())
        raise UsageError(f"{_given(option, device)}: no such Warp device here (available: {available})") from None


def _given(option: str, value) -> str:
    """How an error line names a value: ``--cache DIR`` for the command, ``cache_dir=DIR`` for the hook."""
    return f"{option}{value}" if option.endswith("=") else f"{option} {value}"


def check_cache_folder(folder, *, option: str = "--cache") -> None:
    """Refuse a result-cache path that is a file. A folder that cannot be written is no error: the cache
    is an optimisation, so a read-only shared cache is still read and the bake warns once (core.cache)."""
    if Path(folder).exists() and not Path(folder).is_dir():
        raise UsageError(f"{_given(option, folder)}: is a file, not a folder")


def empty_bake_message(steps) -> str:
    """Why a bake that would author nothing writes nothing: what became of each step."""
    parts = []
    for step in steps:
        if step.action == "skip":
            parts.append(f"{step.name} skipped ({step.reason})" if step.reason else f"{step.name} skipped")
        else:
            parts.append(f"{step.name} authored nothing")
    return f"nothing to bake: {'; '.join(parts) or 'no processors'}; no output was written"
