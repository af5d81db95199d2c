"""The capture: frames, masks, cameras and lighting of one object, and its on-disk format."""

from .model import Camera, CameraResponse, Capture, Environment, Frame, PointLight
from .format import save_capture
from .load import load_capture

__all__ = ["Camera", "CameraResponse", "Capture", "Environment", "Frame", "PointLight", "load_capture", "save_capture"]
