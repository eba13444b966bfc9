"""Geometry shared by every use case: planar transforms, quaternions and 3-D
rigid transforms, oriented boxes (one ``points_in_boxes``), polygons.

Pure numpy, vectorised over leading axes; nothing here knows a file format or
a use case.
"""
from .boxes import (EDGE_FRONT, EDGE_LEFT, EDGE_REAR, EDGE_RIGHT, PointsInBoxes, box_corners, boxes_overlap,
                    oriented_boxes_overlap, points_in_boxes, segment_box_overlap_length)
from .planar import (agent_from_world, norm2d, transform_points, world_from_agent, wrap_angle, yaw_as_rotation33,
                     yaw_from_rotation33)
from .polygons import points_in_polygon, polygon_edges, polygon_self_intersects, polygon_signed_area
from .quaternions import (matrix_to_quat, matrix_to_quat_wxyz, matrix_to_rpy, quat_to_matrix, quat_wxyz_from_yaw,
                          quat_wxyz_to_matrix, rigid_inverse, slerp, transform_matrix, yaw_from_quat_wxyz)

__all__ = [
    "EDGE_FRONT", "EDGE_LEFT", "EDGE_REAR", "EDGE_RIGHT", "PointsInBoxes", "agent_from_world", "box_corners",
    "boxes_overlap", "matrix_to_quat", "matrix_to_quat_wxyz", "matrix_to_rpy", "norm2d", "oriented_boxes_overlap",
    "points_in_boxes", "points_in_polygon", "polygon_edges", "polygon_self_intersects", "polygon_signed_area",
    "quat_to_matrix", "quat_wxyz_from_yaw", "quat_wxyz_to_matrix", "rigid_inverse", "segment_box_overlap_length",
    "slerp", "transform_matrix", "transform_points", "world_from_agent", "wrap_angle", "yaw_as_rotation33",
    "yaw_from_quat_wxyz", "yaw_from_rotation33",
]
