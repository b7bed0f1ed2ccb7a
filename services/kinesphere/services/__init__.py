"""kinesphere.services role package."""
