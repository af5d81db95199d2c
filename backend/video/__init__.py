"""Real-world captures: frames from a video (or a frames folder) and cameras by SfM.

``frames`` decodes and picks sharp frames, ``sfm`` solves the cameras with pycolmap and
``scene_frame`` levels, centres and scales the result into Blender's Z-up world."""
