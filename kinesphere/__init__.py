"""kinesphere: platform-invariant spatial commands (Laban directions) for robots, over Zenoh."""

__version__ = "0.1.0"
