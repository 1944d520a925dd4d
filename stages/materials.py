"""Per-face diffuse albedo and emission from bound materials.

Order of precedence per face: the UsdPreviewSurface bound to the face's
GeomSubset or to the prim (diffuseColor constant, or the mean of a
diffuseColor texture read with OpenImageIO), else ``primvars:displayColor``
(constant, uniform or the mean of other interpolations), else 0.5 grey.
Connections are followed through node graphs and material interface inputs.

A texture that cannot be used (file not found or unreadable, no file, UDIM,
or a source shader other than UsdUVTexture) gives the texture's authored
``inputs:fallback`` (what Hydra shows), else the UsdPreviewSurface default
(diffuseColor 0.18 grey, emissiveColor black), and one warning line naming
the texture, the shader input and the value used.
"""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade

DEFAULT_ALBEDO = (0.5, 0.5, 0.5)
PREVIEW_SURFACE = "UsdPreviewSurface"
UV_TEXTURE = "UsdUVTexture"


class MaterialReader:
    """Reads and caches shading per material, so shared materials are read once."""

    def __init__(self, timecode: Usd.TimeCode, warnings: list | None = None):
        self.timecode = timecode
        self.warnings = warnings if warnings is not None else []
        """Textures that could not be read and the fallback used instead, one line each."""
        self._materials: dict[str, tuple[np.ndarray | None, np.ndarray, str]] = {}
        self._textures: dict[tuple[str, bool], tuple[np.ndarray | None, str]] = {}

    def face_shading(self, prim: Usd.Prim, face_count: int) -> tuple[np.ndarray, np.ndarray, str]:
        """(F, 3) albedo, (F, 3) emission and the prim-level surface shader path ('' if none)."""
        albedo = np.broadcast_to(self._display_color(prim, face_count), (face_count, 3)).astype(np.float32)
        emission = np.zeros((face_count, 3), np.float32)
        binding = UsdShade.MaterialBindingAPI(prim)
        surface = ""
        material, _ = binding.ComputeBoundMaterial()
        if material:
            diffuse, emissive, surface = self._shading(material)
            if diffuse is not None:
                albedo[:] = diffuse
            emission[:] = emissive
        for subset in UsdShade.MaterialBindingAPI.GetMaterialBindSubsets(binding):
            subset_material, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
            if not subset_material:
                continue
            faces = np.asarray(subset.GetIndicesAttr().Get(self.timecode) or [], np.int64)
            faces = faces[(faces >= 0) & (faces < face_count)]
            diffuse, emissive, _ = self._shading(subset_material)
            if diffuse is not None:
                albedo[faces] = diffuse
            emission[faces] = emissive
        return np.clip(albedo, 0.0, 1.0), np.maximum(emission, 0.0), surface

    def _display_color(self, prim: Usd.Prim, face_count: int) -> np.ndarray:
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        values = primvar.ComputeFlattened(self.timecode) if primvar and primvar.HasValue() else None
        if values is None or len(values) == 0:
            return np.array(DEFAULT_ALBEDO, np.float32)
        values = np.asarray(values, np.float32).reshape(-1, 3)
        if primvar.GetInterpolation() == UsdGeom.Tokens.uniform and len(values) == face_count:
            return values
        return values.mean(axis=0)

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


def image_mean(path: str, *, srgb: bool) -> np.ndarray | None:
    """Mean RGB of an image read through OpenImageIO (None if it cannot be read); 8-bit sRGB data is
    linearized first."""
    return _read_image_mean(path, srgb=srgb)[0]


def _read_image_mean(path: str, *, srgb: bool) -> tuple[np.ndarray | None, str]:
    """(mean RGB, '') or (None, OpenImageIO's error)."""
    rgb, error = read_rgb(path, srgb=srgb)
    return (None, error) if rgb is None else (rgb.reshape(-1, 3).mean(axis=0), "")


def read_rgb(path: str, *, srgb: bool) -> tuple[np.ndarray | None, str]:
    """((H, W, 3) float64 RGB, '') or (None, OpenImageIO's error); grey images are repeated into RGB, and
    8-bit data is linearized from sRGB when ``srgb``."""
    import OpenImageIO as oiio

    image = oiio.ImageBuf(path)
    if image.has_error:
        return None, " ".join(image.geterror().split()) or "OpenImageIO cannot read it"
    spec = image.spec()
    pixels = np.asarray(image.get_pixels(oiio.FLOAT), np.float64).reshape(spec.height, spec.width, image.nchannels)
    rgb = pixels[..., :3] if image.nchannels >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if srgb and spec.format == oiio.UINT8:
        rgb = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    return rgb, ""
