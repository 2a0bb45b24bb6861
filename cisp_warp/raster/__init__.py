"""Software rasterizer (visibility buffer + attribute resolve) for the camera and light views."""

from .light_maps import LightMaps
from .rasterizer import GBuffer, Rasterizer, RSMView, SpecularLayer
from .raycast import raycast_back_view, raycast_view
from .views import LightViewSettings, View, ViewParams, camera_view, light_views, shadow_view

__all__ = ["GBuffer", "LightMaps", "LightViewSettings", "RSMView", "Rasterizer", "SpecularLayer", "View", "ViewParams",
           "camera_view", "light_views", "raycast_back_view", "raycast_view", "shadow_view"]
