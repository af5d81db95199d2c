"""Lighting alignment: where the captured environment map sits and how bright it is, estimated
from the frames against a coarse mesh (:func:`align.align_lighting`)."""
