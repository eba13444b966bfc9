"""l5kit's rasterizers (``box_debug``, ``py_semantic``), batched over (scene, frame) rows.

Public API::

    params = RasterParams(map_type="box_debug", raster_size=(112, 112), history_num_frames=10)
    raster = Rasterizer(params, log, scenes=scenes)           # prepared once per log
    images = raster(rows, frames, ego_xy, ego_yaw)             # (B, C, H, W) float32 in [0, 1]
    canvas = raster.canvas(B)                                  # or draw in place, step after step:
    images = raster(rows, frames, ego_xy, ego_yaw, out=canvas) # canvas.image[:B]; redraw when canvas.free
    rasterize(params, log, rows, frames, ego_xy, ego_yaw, scenes=scenes)   # the same, one shot

``draw`` holds the OpenCV-exact scan conversion, ``transforms`` the matrices.
"""
from .boxes import agent_keep
from .params import MAP_TYPES, RasterParams
from .rasterize import Canvas, Rasterizer, rasterize
from .semantic import ActiveFaces, PreparedMap, active_faces
from .transforms import raster_from_local, raster_from_world

__all__ = ["MAP_TYPES", "ActiveFaces", "Canvas", "PreparedMap", "RasterParams", "Rasterizer", "active_faces", "agent_keep",
           "raster_from_local", "raster_from_world", "rasterize"]
