"""kinesphere.clients role package."""
