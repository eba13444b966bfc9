"""Lyft Level 5 (l5kit) data: the zarr dataset (read without zarr 3) and the semantic map
(its protobuf wire format, WGS84 frames)."""
