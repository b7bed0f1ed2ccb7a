"""``kinesphere view``: every robot on the Zenoh network, live in 3D in the browser (viser)."""
