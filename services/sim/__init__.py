"""The sim service: MuJoCo physics as its own Zenoh process (Gazebo's role in the ROS seed)."""
