"""Where the operator's hands come from: the pygame pad, ROS 2 Joy, a recorded session."""
