"""ROS 2 bags without ROS: sqlite3 and mcap storage, PointCloud2 and TF messages."""
