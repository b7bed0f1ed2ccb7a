"""Package discovery for the role folders mapped under ``kinesphere.*``.

pyproject.toml maps ``services/``, ``clients/`` and ``robots/`` onto ``kinesphere.services``,
``kinesphere.clients`` and ``kinesphere.robots``; setuptools' automatic discovery cannot follow
that mapping for sub-packages, so they are listed here.
"""

from setuptools import find_packages, setup

packages = find_packages(include=["kinesphere", "kinesphere.*"])
for role in ("services", "clients", "robots"):
    packages += [f"kinesphere.{p}" for p in find_packages(include=[role, f"{role}.*"])]

setup(packages=packages)
