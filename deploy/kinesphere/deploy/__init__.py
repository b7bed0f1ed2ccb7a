"""The system as operators run it: ``kinesphere up`` (a whole local demo), ``status`` and
``router`` (multi-machine deployments, see ``deploy/``).

Roles are started as separate processes (``python -m kinesphere.cli ...``) and observed only
over Zenoh; nothing here imports a role's process code.
"""
