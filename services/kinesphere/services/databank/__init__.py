"""The databank: the ECL served over Zenoh (pose, compound, catalogue, record), with replicas.

Submodules are imported on demand (``service``, ``process``, ``client``, ``cli``) so that the
``kinesphere`` command stays quick to start.
"""
