"""TIER IV's t4_dataset (nuScenes-style tables), its PCD point clouds and Lanelet2 maps."""
