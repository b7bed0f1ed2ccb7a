"""The recording wing: ``kinesphere record`` and ``replay`` (a Zenoh session to MCAP and back)."""
