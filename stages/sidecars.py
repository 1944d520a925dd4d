"""Sidecar files of a bake layer (textures, .dds, .npz, stream files): named by output and content,
staged under temporary names, owned by the layer that records their digests.

Sidecar files are named ``<layer stem>_<record name>_<content hash>.<ext>``: no output can overwrite
another's. The provenance records each with the SHA-256 of the bytes written (``sidecars``,
``sidecarDigests``), and a re-bake removes a file the previous version recorded and the new one does not
only if it is still that file: in the output's own folder, named as usdbake names sidecars, a plain file
(not a link) with the recorded digest. Nothing a layer says can make a bake delete anything else; a layer
without digests removes nothing. Temporary files are named ``.<output name>.usdbake-tmp-<pid>-<token>...``
and removed on failure; a later bake into the same output removes those a killed process left.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import secrets
import stat
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Sdf, Tf, Vt

from ..core.records import Attribute, File, Texture
from .provenance import is_bake_layer, provenance_of

TEMP_TAG = ".usdbake-tmp-"
"""Marks usdbake's temporary files: ``.<output name>.usdbake-tmp-<pid>-<token>...``."""


@dataclass(frozen=True)
class Sidecar:
    """A Texture or File record with the file it becomes."""

    record: Texture | File
    path: Path
    """Absolute final path."""
    asset_path: str
    """What the layer's asset attributes hold: './name' relative to the layer, or absolute."""


def sidecar_name(record: Texture | File, prefix: str) -> str:
    """``<prefix>_<record path made file-safe, without extension>_<hash8><ext>``.

    The hash is of the content (for a texture: dtype, shape and bytes), so two outputs, or two
    parameter sets, never share a name unless they share the bytes.
    """
    digest = hashlib.sha256()
    if isinstance(record, Texture):
        pixels = np.ascontiguousarray(record.pixels)
        digest.update(f"{pixels.dtype.str}{pixels.shape}".encode())
        digest.update(pixels.tobytes())
    else:
        digest.update(record.data)
    relative = Path(_asset_key(record.path))
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", relative.with_suffix("").as_posix()).strip("_") or "data"
    return f"{prefix}_{stem}_{digest.hexdigest()[:8]}{relative.suffix}"


def assign_sidecars(outputs: list, prefix: str, directory: Path, anchor: Path | None) -> tuple[list, list[Sidecar]]:
    """Name every Texture/File record's file and point the asset attributes that name it there.

    ``anchor`` is the layer's folder (asset paths relative to it), None for an anonymous layer
    (absolute paths: an anonymous layer anchors nothing).
    """
    sidecars: dict[str, Sidecar] = {}
    renamed: dict[str, str] = {}
    for record in outputs:
        if not isinstance(record, (Texture, File)):
            continue
        path = directory / sidecar_name(record, prefix)
        if anchor is None:
            asset = path.as_posix()
        else:
            relative = Path(os.path.relpath(path, anchor)).as_posix()
            asset = relative if relative.startswith("../") else f"./{relative}"
        sidecars.setdefault(path.name, Sidecar(record, path, asset))
        renamed[_asset_key(record.path)] = asset
    if not renamed:
        return list(outputs), []
    rewritten = []
    for record in outputs:
        if isinstance(record, (Texture, File)):
            continue
        if isinstance(record, Attribute) and record.type_name == "asset" and record.value is not None:
            target = renamed.get(_asset_key(str(record.value)))
            if target is not None:
                record = replace(record, value=target)
        rewritten.append(record)
    return rewritten, list(sidecars.values())


def _asset_key(path: str) -> str:
    """A record path or asset value as a comparable relative path ('./a/b.png' and 'a/b.png' match)."""
    return os.path.normpath(path.replace("\\", "/"))


class StagedFiles:
    """Sidecars written under temporary names beside their final ones; commit() renames them into
    place, discard() removes whatever was not committed."""

    def __init__(self, owner: str):
        self.owner = owner
        """The output's file name the temporary names start with."""
        self.pending: list[tuple[Path, Path]] = []
        self.finals: set[Path] = set()
        """Final paths committed."""
        self.created: set[Path] = set()
        """Final paths that did not exist before commit (what to take back if the layer never lands)."""
        self.digests: dict[Path, str] = {}
        """SHA-256 (hex) of each written file's bytes, by final path."""

    def write(self, sidecar: Sidecar) -> None:
        sidecar.path.parent.mkdir(parents=True, exist_ok=True)
        temp = temp_path(sidecar.path.parent, self.owner, sidecar.path.name)
        self.pending.append((temp, sidecar.path))
        if isinstance(sidecar.record, Texture):
            _write_image(sidecar.record.pixels, temp)
        else:
            temp.write_bytes(sidecar.record.data)
        self.digests[sidecar.path] = file_sha256(temp)

    def commit(self) -> None:
        while self.pending:
            temp, final = self.pending[0]
            if not final.exists():
                self.created.add(final)
            os.replace(temp, final)
            self.pending.pop(0)
            self.finals.add(final)

    def discard(self) -> None:
        for temp, _ in self.pending:
            temp.unlink(missing_ok=True)
        self.pending.clear()

    def take_back(self) -> None:
        """Remove the committed files that were new: their layer never came to name them."""
        for path in self.created:
            path.unlink(missing_ok=True)
        self.created.clear()


def temp_path(folder: Path, owner: str, tail: str) -> Path:
    """A recognisable temporary name in ``folder``: ``.<owner>.usdbake-tmp-<pid>-<token>-<tail>``.

    ``tail`` keeps the final extension, which Sdf and OpenImageIO pick the file format by.
    """
    return Path(folder) / f".{owner}{TEMP_TAG}{os.getpid()}-{secrets.token_hex(4)}-{tail}"


def remove_stale_temps(out: Path) -> list[Path]:
    """Remove temporary files an earlier, killed bake into ``out`` left beside it (returns them).

    Only files whose writing process is gone: a bake into the same output running right now in
    another process keeps its files.
    """
    removed = []
    pattern = re.compile(rf"^\.{re.escape(out.name)}{re.escape(TEMP_TAG)}(\d+)-")
    for path in out.parent.glob(f".{out.name}{TEMP_TAG}*"):
        match = pattern.match(path.name)
        if match and path.is_file() and not _process_alive(int(match.group(1))):
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True  # another bake of this process (a thread) may be writing them
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return False
    return True


def file_sha256(path: Path) -> str:
    with open(path, "rb") as file:
        return hashlib.file_digest(file, "sha256").hexdigest()


def sidecar_pattern(prefix: str) -> re.Pattern:
    """The names ``sidecar_name`` gives with ``prefix``: ``<prefix>_<record>_<hash8>[.<ext>]``."""
    return re.compile(rf"{re.escape(prefix)}_[A-Za-z0-9_.-]+_[0-9a-f]{{8}}(\.[A-Za-z0-9]+)?")


def owned_sidecars(layer: Sdf.Layer, *, folder: Path | None = None, prefix: str | None = None) -> dict[Path, str]:
    """{absolute path: recorded SHA-256} of the sidecars a bake layer recorded that it may own.

    A recorded name counts only when it lies directly in ``folder`` (default: the layer's own
    folder; none for an anonymous layer), carries the sidecar name with ``prefix`` (default: the
    layer's file stem) and has a recorded digest. ``..``, absolute paths elsewhere, subfolders, other
    names and a layer written without digests give nothing: a layer's provenance is user-editable
    text, and what it names is not ours to delete or serve unless all of these hold. Whether the
    file is still the one written (not replaced, not a link) is checked where it is used
    (``is_owned_file``).
    """
    if folder is None:
        if not layer.realPath:
            return {}
        folder = Path(layer.realPath).resolve().parent
    if prefix is None:
        if not layer.realPath:
            return {}
        prefix = Path(layer.realPath).stem
    provenance = provenance_of(layer)
    names, digests = provenance.get("sidecars"), provenance.get("sidecarDigests")
    if not all(isinstance(value, (list, tuple, Vt.StringArray)) for value in (names, digests)) \
            or len(names) != len(digests):
        return {}
    folder, pattern = Path(folder), sidecar_pattern(prefix)
    owned = {}
    for name, sha in zip(names, digests):
        if not isinstance(name, str) or not isinstance(sha, str) or not re.fullmatch(r"[0-9a-f]{64}", sha):
            continue
        path = Path(os.path.normpath(folder / name))  # an absolute name replaces folder
        if path.parent == folder and pattern.fullmatch(path.name):
            owned[path] = sha
    return owned


def is_owned_file(path: Path, sha256: str) -> bool:
    """True when ``path`` is a plain file (a link is never followed) whose bytes hash to ``sha256``."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return False
    with os.fdopen(fd, "rb") as file:
        if not stat.S_ISREG(os.fstat(file.fileno()).st_mode):
            return False
        return hashlib.file_digest(file, "sha256").hexdigest() == sha256


def owned_by_file(path: Path) -> dict[Path, str]:
    """The sidecars the bake layer at ``path`` owns (nothing when it is missing or not a bake layer)."""
    if not path.is_file():
        return {}
    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
    except Tf.ErrorException:
        return {}
    if layer is None or not is_bake_layer(layer):
        return {}
    return owned_sidecars(layer, folder=path.resolve().parent, prefix=path.stem)


def remove_sidecars(owned: dict[Path, str]) -> None:
    """Delete the files of ``owned`` ({path: recorded SHA-256}) that are still what the bake wrote."""
    for path, sha in owned.items():
        if is_owned_file(path, sha):
            path.unlink(missing_ok=True)


def write_texture(texture: Texture, directory: str) -> str:
    """Write an image with OpenImageIO (float32/float16 -> EXR as given, uint8/uint16 -> PNG) to
    ``directory / texture.path``; returns the path."""
    path = Path(directory) / texture.path
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_image(texture.pixels, path)
    return str(path)


def _write_image(pixels: np.ndarray, path: Path) -> None:
    import OpenImageIO as oiio

    pixels = np.ascontiguousarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    fmt = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16,
           np.dtype(np.float16): oiio.HALF}.get(pixels.dtype, oiio.FLOAT)
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], fmt)
    output = oiio.ImageOutput.create(str(path))
    if output is None or not output.open(str(path), spec):
        raise OSError(errno.EIO, f"OpenImageIO cannot write {path.name}: {oiio.geterror()}")
    # write_image can return True after short writes (a full disk): its error text is the only sign
    written = output.write_image(pixels)
    error = output.geterror()
    closed = output.close()
    error = error or output.geterror()
    if not written or not closed or error:
        raise OSError(errno.EIO, f"OpenImageIO: {error.splitlines()[0] if error else 'the image was not written'}")
