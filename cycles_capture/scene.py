"""The head's Cycles scene, built with bpy from a job's ``scene.npz`` and ``job.json``.

Skin: the painted texture through a Principled BSDF with subsurface scattering, a roughness map
and the four wrinkle height maps bumped in by a per-vertex colour attribute (``wrinkle``) that
each moment sets. Eyes: a clear coat for the wet cornea's highlight. The mouth's inside and the
lids' lining: wet, a little translucent. Hair: curves with the hair BSDF. Lights: the job's
soft boxes and a dim grey world. Positions arrive in FLAME axes and cross into Blender's through
the project's one conversion.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ..core.data.cycles_hair import Strands
from ..core.for_blender.axes import flame_to_blender
from ..core.for_blender.cameras import blender_camera
from ..operators.import_capture import build_camera

SUBSURFACE_RADIUS = (1.0, 0.37, 0.19)  # skin's mean free path per channel, relative (red scatters furthest)
SUBSURFACE_SCALE = 0.003  # metres: red light travels about 3 mm under the skin
WRINKLE_DEPTH = 0.0008  # metres of bump at a wrinkle map's full value
WRINKLE_DARKENING = 0.4  # how much darker a fully active groove's albedo is
ADAPTIVE_THRESHOLD = 0.02  # Cycles' noise level at which a pixel stops sampling (its default is 0.01)


def _image(name: str, pixels: np.ndarray, colour: bool):
    """A generated image (kept in memory, never saved) from (H,W,C) rows top to bottom (Blender stores them bottom up)."""
    height, width = pixels.shape[:2]
    rgba = np.ones((height, width, 4), np.float32)
    rgba[..., :pixels.shape[2]] = pixels
    if pixels.shape[2] == 1:
        rgba[..., 1:3] = pixels
    image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=not colour)
    image.colorspace_settings.name = "sRGB" if colour else "Non-Color"
    image.alpha_mode = "CHANNEL_PACKED"
    image.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).ravel())
    return image


def _material(name: str):
    material = bpy.data.materials.new(name)
    if material.node_tree is None:
        material.use_nodes = True
    return material, material.node_tree.nodes, material.node_tree.links


def _principled(nodes):
    return next(n for n in nodes if n.type == "BSDF_PRINCIPLED")


def skin_material(albedo, wrinkles, roughness):
    """The skin: texture, subsurface, roughness map, and the wrinkle maps weighted by the mesh's
    ``wrinkle`` attribute into a bump and a slight darkening of the grooves."""
    material, nodes, links = _material("skin")
    bsdf = _principled(nodes)
    texture = nodes.new("ShaderNodeTexImage")
    texture.image = albedo
    rough = nodes.new("ShaderNodeTexImage")
    rough.image = roughness
    maps = nodes.new("ShaderNodeTexImage")
    maps.image = wrinkles
    weight = nodes.new("ShaderNodeAttribute")
    weight.attribute_name = "wrinkle"
    dot = nodes.new("ShaderNodeVectorMath")
    dot.operation = "DOT_PRODUCT"
    links.new(weight.outputs["Color"], dot.inputs[0])
    links.new(maps.outputs["Color"], dot.inputs[1])
    fourth = nodes.new("ShaderNodeMath")
    fourth.operation = "MULTIPLY"
    links.new(weight.outputs["Alpha"], fourth.inputs[0])
    links.new(maps.outputs["Alpha"], fourth.inputs[1])
    depth = nodes.new("ShaderNodeMath")
    depth.operation = "ADD"
    links.new(dot.outputs["Value"], depth.inputs[0])
    links.new(fourth.outputs["Value"], depth.inputs[1])
    bump = nodes.new("ShaderNodeBump")
    bump.invert = True  # the maps hold grooves' depths
    bump.inputs["Distance"].default_value = WRINKLE_DEPTH
    links.new(depth.outputs["Value"], bump.inputs["Height"])
    shade = nodes.new("ShaderNodeMath")
    shade.operation = "MULTIPLY_ADD"
    shade.inputs[1].default_value = -WRINKLE_DARKENING
    shade.inputs[2].default_value = 1.0
    links.new(depth.outputs["Value"], shade.inputs[0])
    darker = nodes.new("ShaderNodeVectorMath")
    darker.operation = "SCALE"
    links.new(texture.outputs["Color"], darker.inputs[0])
    links.new(shade.outputs["Value"], darker.inputs["Scale"])
    links.new(darker.outputs["Vector"], bsdf.inputs["Base Color"])
    links.new(rough.outputs["Color"], bsdf.inputs["Roughness"])
    links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])
    bsdf.inputs["Subsurface Weight"].default_value = 1.0
    bsdf.inputs["Subsurface Radius"].default_value = SUBSURFACE_RADIUS
    bsdf.inputs["Subsurface Scale"].default_value = SUBSURFACE_SCALE
    bsdf.inputs["IOR"].default_value = 1.4
    bsdf.subsurface_method = "BURLEY"  # half random walk's time here, and the look of skin at this scale
    return material


def textured_material(name: str, albedo, roughness: float, coat: float = 0.0, subsurface: float = 0.0):
    """The eyes (a clear coat: the cornea's highlight) and the mouth's wet inside."""
    material, nodes, links = _material(name)
    bsdf = _principled(nodes)
    texture = nodes.new("ShaderNodeTexImage")
    texture.image = albedo
    links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Coat Weight"].default_value = coat
    bsdf.inputs["Coat Roughness"].default_value = 0.02
    bsdf.inputs["Coat IOR"].default_value = 1.376
    bsdf.inputs["Subsurface Weight"].default_value = subsurface
    bsdf.inputs["Subsurface Scale"].default_value = SUBSURFACE_SCALE
    bsdf.subsurface_method = "BURLEY"
    return material


def hair_material(colour):
    material, nodes, links = _material("hair")
    for node in list(nodes):
        if node.type == "BSDF_PRINCIPLED":
            nodes.remove(node)
    hair = nodes.new("ShaderNodeBsdfHairPrincipled")
    hair.parametrization = "COLOR"
    hair.inputs["Color"].default_value = (*[float(c) for c in colour], 1.0)
    hair.inputs["Roughness"].default_value = 0.3
    output = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    links.new(hair.outputs[0], output.inputs["Surface"])
    return material


class HeadScene:
    """The scene of one job; :meth:`pose` sets a moment, :meth:`look_through` a camera."""

    def __init__(self, data, job: dict, cameras: dict, threads: int):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        self.scene = scene = bpy.context.scene
        self._settings(scene, job, threads)
        self.faces = np.asarray(data["faces"])
        self.strands = Strands.from_arrays(data)
        self.head = self._head(data)
        self.hair = self._hair(self.strands)
        self._lights(job)
        self.cameras = {cid: build_camera(blender_camera(c), scene.collection) for cid, c in cameras.items()}

    @staticmethod
    def _settings(scene, job, threads):
        scene.render.engine = "CYCLES"
        cycles = scene.cycles
        cycles.device = "CPU"
        cycles.samples = int(job["samples"])
        cycles.use_adaptive_sampling = True
        cycles.adaptive_threshold = ADAPTIVE_THRESHOLD
        cycles.use_denoising = True
        cycles.denoiser = "OPENIMAGEDENOISE"
        cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        cycles.denoising_prefilter = job["denoising_prefilter"]
        cycles.max_bounces, cycles.diffuse_bounces, cycles.glossy_bounces = 6, 2, 2
        cycles.transparent_max_bounces = 16
        cycles.caustics_reflective = cycles.caustics_refractive = False
        scene.cycles_curves.shape = "RIBBONS"  # strands far thinner than a pixel: flat is enough, and 2× faster
        scene.render.film_transparent = True
        scene.render.use_persistent_data = True
        if threads > 0:
            scene.render.threads_mode = "FIXED"
            scene.render.threads = threads
        scene.view_settings.view_transform = "Standard"
        settings = scene.render.image_settings
        settings.file_format = "OPEN_EXR"
        settings.color_mode = "RGBA"
        settings.color_depth = "16"
        settings.exr_codec = "ZIP"
        world = bpy.data.worlds.new("dome")
        world.color = (job["world_grey"],) * 3
        scene.world = world

    def _head(self, data):
        mesh = bpy.data.meshes.new("head")
        faces = self.faces
        mesh.vertices.add(int(faces.max()) + 1)
        mesh.loops.add(faces.size)
        mesh.polygons.add(len(faces))
        mesh.loops.foreach_set("vertex_index", faces.ravel().astype(np.int32))
        mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
        mesh.polygons.foreach_set("loop_total", np.full(len(faces), 3, np.int32))
        mesh.polygons.foreach_set("use_smooth", np.ones(len(faces), bool))
        uv = mesh.uv_layers.new(name="UVMap")
        uv.data.foreach_set("uv", np.asarray(data["vt"])[np.asarray(data["ft"])].astype(np.float32).ravel())
        mesh.color_attributes.new("wrinkle", "FLOAT_COLOR", "POINT")
        albedo = _image("albedo", np.asarray(data["texture"], np.float32) / 255.0, colour=True)
        wrinkles = _image("wrinkles", np.asarray(data["wrinkles"], np.float32), colour=False)
        roughness = _image("roughness", np.asarray(data["roughness"], np.float32)[..., None], colour=False)
        for material in (skin_material(albedo, wrinkles, roughness),
                         textured_material("eye", albedo, 0.05, coat=1.0),
                         textured_material("mouth", albedo, 0.3, subsurface=0.5),
                         textured_material("lining", albedo, 0.3, subsurface=0.5)):
            mesh.materials.append(material)
        mesh.polygons.foreach_set("material_index", np.asarray(data["material"], np.int32))
        obj = bpy.data.objects.new("head", mesh)
        self.scene.collection.objects.link(obj)
        return obj

    def _hair(self, strands: Strands):
        if not len(strands.face):
            return None
        curves = bpy.data.hair_curves.new("hair")
        count, points = strands.local.shape[:2]
        curves.add_curves([points] * count)
        radius = curves.attributes.get("radius") or curves.attributes.new("radius", "FLOAT", "POINT")
        radius.data.foreach_set("value", strands.radius.astype(np.float32).ravel())
        curves.materials.append(hair_material(strands.colour))
        obj = bpy.data.objects.new("hair", curves)
        self.scene.collection.objects.link(obj)
        return obj

    def _lights(self, job):
        for k, light in enumerate(job["lights"]):
            data = bpy.data.lights.new(f"soft box {k}", "AREA")
            data.shape = "SQUARE"
            data.size = light["size"]
            data.energy = light["power"]
            obj = bpy.data.objects.new(data.name, data)
            position = flame_to_blender(light["position"])
            back = position - flame_to_blender(light["target"])  # an area light shines along its −z
            z = back / np.linalg.norm(back)
            x = np.cross([0.0, 0.0, 1.0], z)
            x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-6 else np.array([1.0, 0.0, 0.0])
            matrix = np.eye(4)
            matrix[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
            matrix[:3, 3] = position
            obj.matrix_world = Matrix(matrix.tolist())
            self.scene.collection.objects.link(obj)

    def pose(self, vertices: np.ndarray, wrinkle: np.ndarray) -> None:
        """Put the head (and its hair) in one moment: FLAME-axes ``vertices``, (V,4) wrinkle weights."""
        mesh = self.head.data
        mesh.vertices.foreach_set("co", flame_to_blender(vertices).astype(np.float32).ravel())
        mesh.color_attributes["wrinkle"].data.foreach_set("color", np.asarray(wrinkle, np.float32).ravel())
        mesh.update()
        if self.hair is not None:
            points = self.strands.positions(np.asarray(vertices, np.float64), self.faces)
            self.hair.data.position_data.foreach_set("vector", flame_to_blender(points).astype(np.float32).ravel())
            self.hair.data.update_tag()

    def look_through(self, camera_id: str) -> None:
        from ..operators.import_capture import apply_render_settings

        apply_render_settings(self.scene, self.cameras[camera_id])
