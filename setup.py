"""The one packaging fact pyproject.toml cannot state: which packages ship.

Every package under ``toolkit/`` is found (a hand-kept list once missed seven, and the built
wheel could not start), and the top-level ``schemas/`` folder, the source of truth for message
definitions and table schemas, ships inside as ``toolkit.schemas`` (``[tool.setuptools.
package-dir]`` maps it; setuptools' ``packages.find`` in pyproject.toml cannot list a mapped
package). Everything else is in pyproject.toml.
"""

from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["toolkit", "toolkit.*"]), "toolkit.schemas"])
