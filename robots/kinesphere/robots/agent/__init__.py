"""The robot agent: a MuJoCo body that follows jerk-limited Ruckig trajectories to ECL poses.

``runtime.Agent`` is the process's heart (commands in, RobotState out); ``controller``
steps MuJoCo with ``trajectory`` (joints) and ``base`` (planar base); ``safety`` holds the
e-stop, deadman and watchdog rules; ``resolver`` asks the databank over Zenoh.
"""
