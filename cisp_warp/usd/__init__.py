"""The USD reader: a stage file -> a validated :class:`~cisp_warp.scene.Scene`, or one clear :class:`SceneError`.

:func:`load_usd` is the face of the package; its parts read one kind of prim each:

| module | reads |
| --- | --- |
| ``load`` | the stage as a whole: traversal, render settings, camera, resolution, assembly (``load_usd``) |
| ``stage`` | opening a stage safely, units and up axis, ``StageContext`` and the value checks |
| ``mesh`` | ``UsdGeom.Mesh`` -> triangles, normals, ``cisp:water`` attributes |
| ``material`` | ``UsdPreviewSurface`` bindings and ``displayColor`` |
| ``lights`` | UsdLux distant, sphere (point) and spot lights |
| ``water`` | ``cisp:water:*`` parameters and rest grid (checked at load) |
| ``guard`` | what USD may open (regular files, size caps) and its parse in a guarded step |
"""

from .load import GBUFFER_BYTES_PER_PIXEL, load_usd, read_camera

__all__ = ["GBUFFER_BYTES_PER_PIXEL", "load_usd", "read_camera"]
