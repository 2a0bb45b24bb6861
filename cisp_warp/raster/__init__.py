"""Software rasterizer (visibility buffer + attribute resolve) for the camera and light views."""

from .rasterizer import GBuffer, LightMaps, Rasterizer, RSMView, SpecularLayer
from .raycast import raycast_view
from .views import View, ViewParams, camera_view, light_views, shadow_view

__all__ = ["GBuffer", "LightMaps", "RSMView", "Rasterizer", "SpecularLayer", "View", "ViewParams",
           "camera_view", "light_views", "raycast_view", "shadow_view"]
