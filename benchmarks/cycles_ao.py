"""Reference AO lightmap baked by Blender Cycles (CPU), for comparing usdbake's AO baker at equal error.

Runs in a separate venv with the `bpy` PyPI package (no usdbake imports):

    /work/bpyvenv/bin/python benchmarks/cycles_ao.py IN.npz OUT.npz

IN.npz:  positions (V,3) f32, triangles (T,3) i32, uvs (T,3,2) f32 per-corner UVs in [0,1],
         width, height, samples (Cycles AA samples per texel = AO rays per texel), margin (texels, EXTEND mode),
         optional: threads (default 2), smooth (0/1, default 0 = flat face normals),
         normals (T,3,3) f32: unit shading normal at each triangle corner (corner order as `triangles`),
         set as the mesh's custom normals (implies smooth shading; `smooth` is then ignored),
         distance (AO ray length, default 1e9 = unlimited),
         occluder_positions (W,3) / occluder_triangles (U,3): extra geometry that occludes but is not baked.
OUT.npz: ao (height, width) f32, row y / column x = texel centred at UV ((x+.5)/width, (y+.5)/height);
         texels not covered by any triangle (after the margin fill) are 0.
         bake_seconds (the bake operator only), setup_seconds (scene build), blender_version.

Measured behaviour (Blender 5.0.1): one cosine-distributed AO ray per sample, point-sampled at the texel
centre (no sub-texel jitter), Tabulated Sobol (stratified: texel noise ~4x below i.i.d. at 256 spp),
deterministic (seed 0); the baked side is the winding (right-hand) normal side; any hit occludes,
back faces included; the AO distance is honoured exactly.
"""

import sys
import time

import numpy as np

import bpy


def set_corner_normals(mesh, normals):
    """Custom normals, one per loop (loops are in triangle-corner order), used as given.

    Blender 4.5+ stores "free" custom normals as a float3 corner attribute named custom_normal: one
    foreach_set, exact (read back from mesh.corner_normals bit for bit), ~1 ms for 130k triangles.
    Older releases only have normals_split_custom_set, which encodes each normal in its corner fan's
    space as two int16 (errors up to ~0.01 in the vector) and takes ~0.25 s for 130k triangles.
    """
    normals = np.asarray(normals, np.float32).reshape(-1, 3)
    if len(normals) != len(mesh.loops):
        raise ValueError(f"normals: {len(normals)} corners for a mesh of {len(mesh.loops)}")
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    if not np.all(np.isfinite(length)) or np.any(length == 0):
        raise ValueError("normals: zero-length or non-finite corner normals")
    normals = np.ascontiguousarray(normals / length)
    if bpy.app.version >= (4, 5, 0):
        attribute = mesh.attributes.new("custom_normal", "FLOAT_VECTOR", "CORNER")
        attribute.data.foreach_set("vector", normals.ravel())
    else:
        mesh.normals_split_custom_set(normals)


def add_mesh(name, positions, triangles, uvs=None, smooth=False, normals=None):
    """One mesh object from numpy arrays via foreach_set (fast for 300k triangles).

    ``normals`` (T,3,3): custom corner normals; the faces are then smooth-shaded, so that Cycles
    interpolates the custom normals across each triangle (a sharp face would use its face normal).
    """
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    triangles = np.ascontiguousarray(triangles, np.int32).reshape(-1, 3)
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(positions))
    mesh.vertices.foreach_set("co", positions.ravel())
    mesh.loops.add(triangles.size)
    mesh.loops.foreach_set("vertex_index", triangles.ravel())  # loops in triangle corner order
    mesh.polygons.add(len(triangles))
    mesh.polygons.foreach_set("loop_start", np.arange(0, triangles.size, 3, dtype=np.int32))
    mesh.update(calc_edges=True)
    smooth = bool(smooth) or normals is not None
    mesh.polygons.foreach_set("use_smooth", np.full(len(triangles), smooth))
    if uvs is not None:
        layer = mesh.uv_layers.new(name="UVMap")
        layer.uv.foreach_set("vector", np.ascontiguousarray(uvs, np.float32).ravel())
    if normals is not None:
        set_corner_normals(mesh, normals)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def main(in_path, out_path):
    data = np.load(in_path)
    get = lambda key, default: data[key].item() if key in data else default
    width, height = int(data["width"]), int(data["height"])

    started = time.perf_counter()
    bpy.ops.wm.read_factory_settings(use_empty=True)  # no default cube/light/camera
    scene = bpy.context.scene
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.light_settings.distance = float(get("distance", 1e9))  # AO ray length (Cycles honours it)

    normals = data["normals"] if "normals" in data else None
    target = add_mesh("Target", data["positions"], data["triangles"], data["uvs"], smooth=get("smooth", 0),
                      normals=normals)
    if "occluder_positions" in data:
        add_mesh("Occluder", data["occluder_positions"], data["occluder_triangles"])

    # Bake target: a float, non-colour image in an Image Texture node that is the active node.
    image = bpy.data.images.new("AO", width, height, alpha=False, float_buffer=True, is_data=True)
    material = bpy.data.materials.new("AOBake")
    if material.node_tree is None:  # Blender 5 materials come with nodes (Principled BSDF + output)
        material.use_nodes = True
    node = material.node_tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    material.node_tree.nodes.active = node
    target.data.materials.append(material)
    # Smooth shading and custom normals: AO rays are cosine-distributed about the interpolated shading
    # normal (rays that dip under the flat triangle are traced too). Cycles' default 0.1 "shadow
    # terminator geometry offset" lifts ray origins off smooth triangles towards the curved surface;
    # disable it so rays start on the triangle itself.
    target.shadow_terminator_geometry_offset = 0.0

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.render.threads_mode = "FIXED"
    scene.render.threads = int(get("threads", 2))
    scene.cycles.samples = int(data["samples"])
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    bake = scene.render.bake
    bake.use_clear = True
    bake.margin = int(data["margin"])
    bake.margin_type = "EXTEND"  # exactly `margin` texels; default ADJACENT_FACES fills ~margin/2 at open edges
    bake.target = "IMAGE_TEXTURES"
    bake.use_selected_to_active = False

    for obj in scene.objects:  # bake the target only; occluders just block rays
        obj.select_set(obj is target)
    bpy.context.view_layer.objects.active = target
    setup_seconds = time.perf_counter() - started

    started = time.perf_counter()
    bpy.ops.object.bake(type="AO")
    bake_seconds = time.perf_counter() - started

    pixels = np.empty(width * height * 4, np.float32)
    image.pixels.foreach_get(pixels)  # RGBA, bottom row (v near 0) first: row y = v of (y+.5)/height
    ao = pixels.reshape(height, width, 4)[:, :, 0].copy()
    np.savez(out_path, ao=ao, bake_seconds=bake_seconds, setup_seconds=setup_seconds,
             blender_version=bpy.app.version_string)
    print(f"cycles_ao: {width}x{height}, {len(data['triangles'])} tris, bake {bake_seconds:.3f}s, "
          f"setup {setup_seconds:.3f}s, Blender {bpy.app.version_string}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
