"""The package list, computed: the repository's root is the package ``fluidsense``
(docs/architecture.md, "One namespace"), and these folders are its subpackages. Everything
else lives in pyproject.toml. The studies (lab/), the tests, docs, examples and firmware
are not in the wheel, and neither is this file."""

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

PARTS = ["cli", "client", "common", "config", "controller", "daemon", "drivers", "simulator", "tasks"]


class BuildPy(build_py):
    def find_package_modules(self, package, package_dir):
        modules = super().find_package_modules(package, package_dir)
        return [m for m in modules if not (package == "fluidsense" and m[1] == "setup")]


setup(packages=["fluidsense"] + [f"fluidsense.{name}" for name in
                                 find_packages(include=[p for part in PARTS for p in (part, f"{part}.*")])],
      package_dir={"fluidsense": "."}, cmdclass={"build_py": BuildPy})
