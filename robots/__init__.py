"""kinesphere.robots role package."""
