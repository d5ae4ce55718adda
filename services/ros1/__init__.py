"""`zensim ros1`: the ROS 1 gateway (docs/ros.md)."""
