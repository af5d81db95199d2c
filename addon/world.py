"""The World environment with the backend's convention (docs/capture-format.md):
Texture Coordinate (Generated) -> Mapping (Point, rotation Z) -> Environment Texture
(equirectangular) -> Background (strength) -> World Output."""

import math
from pathlib import Path

import bpy

from .io.errors import AddonInputError, require

ENV_SUFFIXES = {".exr", ".hdr"}


def load_environment_image(path: str | Path) -> bpy.types.Image:
    """Load an equirectangular (2:1) EXR/HDR map; raises (and loads nothing) when it is not one."""
    path = Path(path)
    require(path.is_file(), path, "environment map not found", "choose an .exr or .hdr file")
    require(path.suffix.lower() in ENV_SUFFIXES, path, "not an EXR or HDR file",
            "convert the environment map to OpenEXR or Radiance HDR")
    try:
        image = bpy.data.images.load(str(path), check_existing=True)
    except RuntimeError as err:
        raise AddonInputError(path, "cannot read the environment map", "re-export it as EXR") from err
    w, h = image.size
    if not (w > 0 and h > 0 and abs(w - 2 * h) <= 1):
        if image.users == 0:
            bpy.data.images.remove(image)
        raise AddonInputError(path, f"environment map is {w}x{h}, not 2:1 equirectangular",
                              "use a latitude-longitude (2:1) panorama")
    return image


def set_environment(world: bpy.types.World, image: bpy.types.Image, strength: float,
                    rotation_z_deg: float) -> None:
    """Rebuild ``world``'s nodes as the convention's chain."""
    if bpy.app.version < (5, 0, 0):  # always on (and deprecated) from Blender 5
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    coords = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(rotation_z_deg))
    env = nodes.new("ShaderNodeTexEnvironment")
    env.projection = "EQUIRECTANGULAR"
    env.image = image
    background = nodes.new("ShaderNodeBackground")
    background.inputs["Strength"].default_value = strength
    output = nodes.new("ShaderNodeOutputWorld")
    links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    links.new(env.outputs["Color"], background.inputs["Color"])
    links.new(background.outputs["Background"], output.inputs["Surface"])
    for i, node in enumerate((coords, mapping, env, background, output)):
        node.location = (i * 250 - 600, 0)


ESTIMATED_MAP = "environment.exr"  # written by reconstruct --lighting estimate (docs/protocol.md)


def load_estimated_environment(scene: bpy.types.Scene, run_dir: str | Path) -> bool:
    """Light ``scene``'s World with the map a ``--lighting estimate`` run fitted
    (RUN/environment.exr, Blender's convention, rotation 0, strength 1); False when the run has
    none. The image is re-read, so a second run into the same folder shows its own map."""
    path = Path(run_dir) / ESTIMATED_MAP
    if not path.is_file():
        return False
    image = load_environment_image(path)
    image.reload()
    if scene.world is None:
        scene.world = bpy.data.worlds.new("SfT World")
    set_environment(scene.world, image, 1.0, 0.0)
    return True
