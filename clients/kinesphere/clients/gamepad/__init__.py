"""The gamepad wing: the streaming loop (``kinesphere gamepad``), its mapping, drive and HUD."""
