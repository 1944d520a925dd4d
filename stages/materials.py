"""Per-face diffuse albedo and emission from bound materials.

Order of precedence per face: the UsdPreviewSurface bound to the face's
GeomSubset or to the prim (diffuseColor constant, or the mean of a
diffuseColor texture read with OpenImageIO), else ``primvars:displayColor``
(constant, uniform or the mean of other interpolations), else 0.5 grey.
Connections are followed through node graphs and material interface inputs.

A ``displayColor`` OpenUSD gives no colour to (UsdGeomGprim declares it ``color3f[]``: a string,
token, int or other non-colour value, a length that does not fit its interpolation, indices
outside its values) is what a renderer ignores: the 0.5 grey is used, with one warning line naming
the prim, the value and the fallback, as for a texture that cannot be used. The values of any
precision (``color3d[]``, ``float3[]``, ...) are colours, and one value may be a scalar.

A texture that cannot be used (file not found or unreadable, no file, UDIM,
or a source shader other than UsdUVTexture) gives the texture's authored
``inputs:fallback`` (what Hydra shows), else the UsdPreviewSurface default
(diffuseColor 0.18 grey, emissiveColor black), and one warning line naming
the texture, the shader input and the value used.

Glazing (``face_transmittance``): the visible transmittance at normal incidence of each face, in order
of precedence: ``bake:transmittance`` (a float) on the mesh prim, else on the face's bound Material
(GeomSubset bindings included), else 1 - ``inputs:opacity`` of its UsdPreviewSurface (a constant, or
the mean of the r, g or b channel of the UsdUVTexture it is connected to), else 0 (opaque). A
UsdPreviewSurface with ``opacityThreshold`` > 0 is a cutout mask, not glass: opaque. An opacity the
reader cannot evaluate (a texture's alpha, another shader, an unreadable file) is opaque, with one
warning line. A value that is not a float, not finite or outside [0, 1] raises StageError naming the
prim, the attribute and the value.
"""

from __future__ import annotations

import re

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade

from ..core.errors import StageError
from .images import image_mean

DEFAULT_ALBEDO = (0.5, 0.5, 0.5)
COLOR_TYPE = re.compile(r"^(color3[fdh]|(float|double|half)3)$")
"""Scalar types whose values are RGB colours (displayColor is declared color3f[])."""
PREVIEW_SURFACE = "UsdPreviewSurface"
UV_TEXTURE = "UsdUVTexture"
TRANSMITTANCE = "bake:transmittance"
"""Float attribute on a mesh prim or a Material: the visible transmittance at normal incidence (glazing)."""
FLOAT_TYPES = (Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Double, Sdf.ValueTypeNames.Half)
CHANNELS = {"r": 0, "g": 1, "b": 2}
"""UsdUVTexture outputs whose mean the reader evaluates (stages.images reads RGB, not alpha)."""


class MaterialReader:
    """Reads and caches shading per material, so shared materials are read once."""

    def __init__(self, timecode: Usd.TimeCode, warnings: list | None = None):
        self.timecode = timecode
        self.warnings = warnings if warnings is not None else []
        """Textures that could not be read and the fallback used instead, one line each."""
        self._materials: dict[str, tuple[np.ndarray | None, np.ndarray, str]] = {}
        self._textures: dict[tuple[str, bool], tuple[np.ndarray | None, str]] = {}
        self._transmittances: dict[str, float] = {}

    def face_shading(self, prim: Usd.Prim, face_count: int) -> tuple[np.ndarray, np.ndarray, str]:
        """(F, 3) albedo, (F, 3) emission and the prim-level surface shader path ('' if none)."""
        albedo = np.broadcast_to(self._display_color(prim, face_count), (face_count, 3)).astype(np.float32)
        emission = np.zeros((face_count, 3), np.float32)
        surface = ""
        for material, faces in self._bindings(prim, face_count):
            diffuse, emissive, path = self._shading(material)
            if diffuse is not None:
                albedo[faces] = diffuse
            emission[faces] = emissive
            if isinstance(faces, slice):
                surface = path
        return np.clip(albedo, 0.0, 1.0), np.maximum(emission, 0.0), surface

    def subset_surfaces(self, prim: Usd.Prim) -> tuple[tuple[str, str], ...]:
        """(GeomSubset path, its bound UsdPreviewSurface shader path) of each material-bound GeomSubset of the
        prim whose material has one: where a texture the bake wires into the prim's surface must also go."""
        out = []
        for subset in UsdShade.MaterialBindingAPI.GetMaterialBindSubsets(UsdShade.MaterialBindingAPI(prim)):
            material, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
            surface = self._shading(material)[2] if material else ""
            if surface:
                out.append((str(subset.GetPath()), surface))
        return tuple(out)

    def _bindings(self, prim: Usd.Prim, face_count: int):
        """(material, faces) of the prim's own binding (faces: a slice of all) then of each GeomSubset bound to
        a material (faces: its valid indices), in the order a later one overrides an earlier one."""
        binding = UsdShade.MaterialBindingAPI(prim)
        material, _ = binding.ComputeBoundMaterial()
        if material:
            yield material, slice(None)
        for subset in UsdShade.MaterialBindingAPI.GetMaterialBindSubsets(binding):
            subset_material, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
            if not subset_material:
                continue
            faces = np.asarray(subset.GetIndicesAttr().Get(self.timecode) or [], np.int64)
            yield subset_material, faces[(faces >= 0) & (faces < face_count)]

    def face_transmittance(self, prim: Usd.Prim, face_count: int) -> np.ndarray:
        """(F,) float32 visible transmittance at normal incidence per face, in [0, 1], 0 for opaque faces
        (precedence in the module docstring). Raises StageError for a bad ``bake:transmittance`` or opacity."""
        own = self._authored_transmittance(prim)
        if own is not None:
            return np.full(face_count, own, np.float32)
        transmittance = np.zeros(face_count, np.float32)
        for material, faces in self._bindings(prim, face_count):
            transmittance[faces] = self._material_transmittance(material)
        return transmittance

    def _material_transmittance(self, material: UsdShade.Material) -> float:
        key = str(material.GetPath())
        if key not in self._transmittances:
            own = self._authored_transmittance(material.GetPrim())
            self._transmittances[key] = own if own is not None else self._opacity_transmittance(material)
        return self._transmittances[key]

    def _authored_transmittance(self, prim: Usd.Prim) -> float | None:
        """The prim's ``bake:transmittance``, checked; None where it has no value authored."""
        attribute = prim.GetAttribute(TRANSMITTANCE)
        if not attribute or not attribute.HasAuthoredValue():
            return None
        return _unit_share(attribute, attribute.Get(self.timecode))

    def _opacity_transmittance(self, material: UsdShade.Material) -> float:
        """1 - opacity of the material's UsdPreviewSurface (0 without one, or for a cutout mask)."""
        shader = material.ComputeSurfaceSource()[0]
        if not shader or shader.GetIdAttr().Get() != PREVIEW_SURFACE:
            return 0.0
        threshold = _value_of(shader.GetInput("opacityThreshold"), self.timecode)
        if isinstance(threshold, (int, float)) and threshold > 0:
            return 0.0  # alpha-tested cutout: a renderer draws the face opaque or not at all, never as glass
        shader_input = shader.GetInput("opacity")
        sources = shader_input.GetValueProducingAttributes() if shader_input else []
        if not sources:
            return 0.0
        source = sources[0]
        if UsdShade.Utils.GetType(source.GetName()) == UsdShade.AttributeType.Input:
            if not source.HasAuthoredValue():
                return 0.0
            return 1.0 - _unit_share(source, source.Get(self.timecode))
        where = f"{shader.GetPath()}.inputs:opacity"
        texture = UsdShade.Shader(source.GetPrim())
        output = source.GetBaseName()
        if texture.GetIdAttr().Get() != UV_TEXTURE:
            shader_id = texture.GetIdAttr().Get() or "a shader with no info:id"
            return self._opaque(f"{where}: connected to {texture.GetPath()}, {shader_id}, which is not evaluated")
        if output not in CHANNELS:
            return self._opaque(f"{where}: connected to {source.GetPath()}; only the r, g and b outputs of a "
                                f"UsdUVTexture are read")
        mean, problem = self._texture_mean(texture)
        if mean is None:
            return self._opaque(f"{where}: {problem}")
        return float(np.clip(1.0 - mean[CHANNELS[output]], 0.0, 1.0))

    def _opaque(self, problem: str) -> float:
        """No transmittance, and one warning line saying why."""
        warning = f"{problem}; the faces bound to it are treated as opaque (no glazing)"
        if warning not in self.warnings:
            self.warnings.append(warning)
        return 0.0

    def _display_color(self, prim: Usd.Prim, face_count: int) -> np.ndarray:
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        if not primvar or not primvar.HasValue():
            return np.array(DEFAULT_ALBEDO, np.float32)
        values, problem = self._display_color_values(prim, primvar, face_count)
        if problem:
            warning = (f"{prim.GetPath()}.primvars:displayColor: {problem}; using the fallback albedo "
                       f"({', '.join(f'{v:g}' for v in DEFAULT_ALBEDO)})")
            if warning not in self.warnings:
                self.warnings.append(warning)
            return np.array(DEFAULT_ALBEDO, np.float32)
        if values is None or len(values) == 0:
            return np.array(DEFAULT_ALBEDO, np.float32)
        if primvar.GetInterpolation() == UsdGeom.Tokens.uniform and len(values) == face_count:
            return values
        return values.mean(axis=0)

    def _display_color_values(self, prim: Usd.Prim, primvar: UsdGeom.Primvar,
                              face_count: int) -> tuple[np.ndarray | None, str]:
        """((N, 3) float32 colours, '') or (None, why OpenUSD gives the value no colour)."""
        authored = primvar.GetAttr().Get(self.timecode)
        declared = authored_type(primvar.GetAttr())
        value = f"{declared} {_plain(authored)}"
        if not COLOR_TYPE.match(str(declared.scalarType)):
            return None, f"{value} is not a colour (UsdGeom declares displayColor color3f[])"
        interpolation = primvar.GetInterpolation()
        count = self._element_count(prim, interpolation, face_count)
        if count is None:
            return None, (f"interpolation {interpolation!r} is not one of OpenUSD's (constant, uniform, varying, "
                          f"vertex, faceVarying)")
        indices = primvar.GetIndicesAttr()
        if indices and indices.HasAuthoredValue():
            if authored_type(indices) != Sdf.ValueTypeNames.IntArray:
                return None, f"indices of type {authored_type(indices)} (indices must be int[])"
            index = np.asarray(indices.Get(self.timecode) or [], np.int64)
            held = len(authored or []) // max(1, primvar.GetElementSize())
            outside = np.flatnonzero((index < 0) | (index >= held))
            if len(outside):  # found here, before ComputeFlattened prints a warning of its own
                first = int(outside[0])
                return None, (f"index {int(index[first])} in its indices (position {first}) is outside its "
                              f"{held} values (0..{held - 1})")
        flattened = primvar.ComputeFlattened(self.timecode)
        if flattened is None:
            return None, ""
        values = np.asarray(flattened if declared.isArray else [flattened], np.float32).reshape(-1, 3)
        expected = count * max(1, primvar.GetElementSize())
        if len(values) and len(values) != expected:
            if interpolation == UsdGeom.Tokens.constant:
                return None, f"{value}: {len(values)} constant values (one is needed)"
            noun = {"uniform": "faces", "faceVarying": "face-vertices"}.get(interpolation, "points")
            return None, f"{value}: {len(values)} {interpolation} values for {count} {noun}"
        return values, ""

    def _element_count(self, prim: Usd.Prim, interpolation: str, face_count: int) -> int | None:
        """Values a primvar of ``interpolation`` holds on ``prim`` (elementSize 1); None if not an interpolation."""
        mesh = UsdGeom.Mesh(prim)
        if interpolation == UsdGeom.Tokens.constant:
            return 1
        if interpolation == UsdGeom.Tokens.uniform:
            return face_count
        if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
            return len(mesh.GetPointsAttr().Get(self.timecode) or [])
        if interpolation == UsdGeom.Tokens.faceVarying:
            return len(mesh.GetFaceVertexIndicesAttr().Get(self.timecode) or [])
        return None

    def _shading(self, material: UsdShade.Material) -> tuple[np.ndarray | None, np.ndarray, str]:
        key = str(material.GetPath())
        if key not in self._materials:
            self._materials[key] = self._read_material(material)
        return self._materials[key]

    def _read_material(self, material: UsdShade.Material):
        shader = material.ComputeSurfaceSource()[0]
        if not shader or shader.GetIdAttr().Get() != PREVIEW_SURFACE:
            return None, np.zeros(3, np.float32), ""
        diffuse = self._color_input(shader, "diffuseColor", (0.18, 0.18, 0.18))
        emissive = self._color_input(shader, "emissiveColor", (0.0, 0.0, 0.0))
        return diffuse, emissive, str(shader.GetPath())

    def _color_input(self, shader: UsdShade.Shader, name: str, fallback) -> np.ndarray:
        shader_input = shader.GetInput(name)
        # What produces the value: a shader output (a texture), or an input holding a value, followed
        # through node graphs and the material's interface inputs.
        sources = shader_input.GetValueProducingAttributes() if shader_input else []
        if not sources:
            return np.array(fallback, np.float32)
        source = sources[0]
        if UsdShade.Utils.GetType(source.GetName()) == UsdShade.AttributeType.Input:
            value = source.Get(self.timecode)
            return np.array(value if value is not None else fallback, np.float32)
        texture = UsdShade.Shader(source.GetPrim())
        if texture.GetIdAttr().Get() != UV_TEXTURE:
            shader_id = texture.GetIdAttr().Get() or "a shader with no info:id"
            return self._fall_back(f"{texture.GetPath()}: {shader_id} is not evaluated", None, shader, name, fallback)
        mean, problem = self._texture_mean(texture)
        return mean if mean is not None else self._fall_back(problem, texture, shader, name, fallback)

    def _fall_back(self, problem: str, texture: UsdShade.Shader | None, shader: UsdShade.Shader, name: str,
                   fallback) -> np.ndarray:
        """The UsdUVTexture's authored ``inputs:fallback`` (what Hydra shows for an unreadable texture),
        else the UsdPreviewSurface default for the input; says which, once per texture and input."""
        authored = _value_of(texture.GetInput("fallback"), self.timecode) if texture else None  # float4
        value = np.array(list(authored)[:3] if authored is not None else fallback, np.float32)
        origin = "the texture's inputs:fallback" if authored is not None else "the UsdPreviewSurface default"
        warning = (f"{problem}; {shader.GetPath()}.inputs:{name} falls back to "
                   f"({', '.join(f'{v:.4g}' for v in value)}), {origin}")
        if warning not in self.warnings:
            self.warnings.append(warning)
        return value

    def _texture_mean(self, texture: UsdShade.Shader) -> tuple[np.ndarray | None, str]:
        """Mean colour of a UsdUVTexture's file (linearized when it is 8-bit sRGB), times scale + bias;
        or None and why the file could not be read."""
        asset = _value_of(texture.GetInput("file"), self.timecode)
        where = f"{texture.GetPath()}.inputs:file"
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:
            return None, f"{where}: no texture file authored"
        if "<UDIM>" in asset.path:
            return None, f"{where}: UDIM texture {asset.path} is not read"
        path = asset.resolvedPath
        if not path:
            return None, f"{where}: texture {asset.path} not found"
        color_space = _value_of(texture.GetInput("sourceColorSpace"), self.timecode) or "auto"
        key = (path, color_space != "raw")  # one file may be read raw by one texture, as sRGB by another
        if key not in self._textures:
            self._textures[key] = _read_image_mean(path, srgb=key[1])
        mean, error = self._textures[key]
        if mean is None:
            return None, f"{where}: texture {asset.path} cannot be read ({error})"
        scale = _vec_input(texture, "scale", (1, 1, 1, 1), self.timecode)[:3]
        bias = _vec_input(texture, "bias", (0, 0, 0, 0), self.timecode)[:3]
        return (mean * scale + bias).astype(np.float32), ""


def authored_type(attribute: Usd.Attribute) -> Sdf.ValueTypeName:
    """The type the strongest layer declares. A schema attribute (``normals``, ``primvars:displayColor``)
    reports its schema's type whatever a layer wrote, but holds the value the layer wrote."""
    stack = attribute.GetPropertyStack(Usd.TimeCode.Default())
    return Sdf.ValueTypeNames.Find(str(stack[0].typeName)) if stack else attribute.GetTypeName()


def _unit_share(attribute: Usd.Attribute, value) -> float:
    """``value`` of ``attribute`` (a transmittance or an opacity) as a float in [0, 1]; StageError naming
    the prim, the attribute and the value when it is not a float, not finite, or outside [0, 1]."""
    path, name = str(attribute.GetPrim().GetPath()), attribute.GetName()
    declared = authored_type(attribute)
    if declared not in FLOAT_TYPES or not isinstance(value, (float, np.floating)):
        raise StageError(path, name, f"{declared} {_plain(value)} is not a float (a share of light in [0, 1])")
    if not np.isfinite(value) or not 0.0 <= value <= 1.0:
        raise StageError(path, name, f"{_plain(value)} is outside [0, 1]")
    return float(value)


def _plain(value, *, limit: int = 4) -> str:
    """A USD value as a person writes it: ``"red"``, ``7``, ``0.5``, ``(1, 0, 0)``, ``[1, 2, ...] (9 values)``."""
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value)).lower()
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):g}"
    if not hasattr(value, "__len__"):
        return str(value)
    items = list(value)
    shown = ", ".join(_plain(item, limit=limit) for item in items[:limit])
    if "Array" not in type(value).__name__ and not isinstance(value, list):
        return f"({shown})"  # a Gf vector
    return f"[{shown}, ...] ({len(items)} values)" if len(items) > limit else f"[{shown}]"


def _value_of(shader_input: UsdShade.Input | None, timecode):
    """An input's value, following connections to interface inputs; None if it has none."""
    if not shader_input:
        return None
    sources = shader_input.GetValueProducingAttributes()
    if sources and UsdShade.Utils.GetType(sources[0].GetName()) == UsdShade.AttributeType.Input:
        return sources[0].Get(timecode)
    return None


def _vec_input(shader: UsdShade.Shader, name: str, fallback, timecode) -> np.ndarray:
    shader_input = shader.GetInput(name)
    value = shader_input.Get(timecode) if shader_input else None
    return np.array(value if value is not None else fallback, np.float64)


def _read_image_mean(path: str, *, srgb: bool) -> tuple[np.ndarray | None, str]:
    """(mean RGB, '') or (None, OpenImageIO's error); the file is read strip by strip (stages.images)."""
    try:
        return image_mean(path, srgb=srgb), ""
    except ValueError as error:
        return None, str(error)
