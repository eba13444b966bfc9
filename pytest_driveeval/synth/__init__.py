"""Data makers for the demo and the tests: plausible L5 scenes (zarr), t4_datasets
with a ROS 2 bag of ray-cast lidar clouds.  Nothing at evaluation time imports this."""
