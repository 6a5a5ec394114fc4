"""Ship ``resources/`` inside the package.

The npe2 manifest lives in the package (``car_napari/napari.yaml``, the
entry point; package data in pyproject.toml; the top-level napari.yaml is
the same file, where the project's layout shows it). The sample data stay at the
top of the repository: a regular build copies them into the wheel
(``car_napari/_resources/``); an editable install serves the package from
the source tree, and the sample loader reads ``resources/`` in place.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

TOP = Path(__file__).resolve().parent
SHIPPED_RESOURCES = ("*.png", "*.jpg", "*.txt", "README.md")
UNSHIPPED_RESOURCES = ("screenshot.png",)


class BuildWithResources(build_py):
    def run(self):
        if not getattr(self, "editable_mode", False):
            # build/ outlives a build: start the package afresh so no deleted module ships
            shutil.rmtree(Path(self.build_lib) / "car_napari", ignore_errors=True)
        super().run()
        if getattr(self, "editable_mode", False):
            return
        target = Path(self.build_lib) / "car_napari" / "_resources"
        target.mkdir(exist_ok=True)
        for pattern in SHIPPED_RESOURCES:
            for path in (TOP / "resources").glob(pattern):
                if path.name not in UNSHIPPED_RESOURCES:
                    shutil.copyfile(path, target / path.name)


setup(cmdclass={"build_py": BuildWithResources})
