"""kinesphere.platforms: the platform descriptions every role reads a robot body from."""
