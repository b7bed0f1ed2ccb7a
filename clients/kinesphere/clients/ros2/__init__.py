"""The ROS 2 wing: ``kinesphere ros2 bridge`` (live kinesphere robots seen by ROS 2 tools)."""
