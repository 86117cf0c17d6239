"""Package discovery only; all metadata lives in pyproject.toml.

schemas/ and services/ sit at the top of the repository but install as followbot.schemas and
followbot.services (see [tool.setuptools] package-dir). setuptools cannot discover packages
through such a mapping, so they are listed here, found the ordinary way.
"""

from setuptools import find_packages, setup

_MAPPED = ("schemas", "services")
packages = [
    "followbot",
    *(f"followbot.{p}" for p in find_packages(".", include=[f"{m}*" for m in _MAPPED])),
]

setup(packages=packages)
