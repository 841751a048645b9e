"""Headless preview rendering, video/GIF writing, plots and mesh-sequence export."""

from ._camera import Camera
from ._renderer import Renderer

__all__ = ["Camera", "Renderer"]
