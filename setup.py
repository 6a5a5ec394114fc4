"""Ship the top-level ``napari.yaml`` and ``resources/`` inside the package.

The layout keeps the npe2 manifest and the sample data at the top of the
repository; napari finds a plugin's manifest inside its package
(``car_napari/napari.yaml``, the entry point). A regular build copies both
into the wheel (``car_napari/napari.yaml``, ``car_napari/_resources/``). An
editable install serves the package from the source tree, so there the
manifest is copied next to the code (git-ignored); the sample loader reads
``resources/`` in place.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

TOP = Path(__file__).resolve().parent
SHIPPED_RESOURCES = ("*.png", "*.jpg", "*.txt", "README.md")
UNSHIPPED_RESOURCES = ("screenshot.png",)


class BuildWithManifest(build_py):
    def run(self):
        if not getattr(self, "editable_mode", False):
            # build/ outlives a build: start the package afresh so no deleted module ships
            shutil.rmtree(Path(self.build_lib) / "car_napari", ignore_errors=True)
        super().run()
        if getattr(self, "editable_mode", False):
            shutil.copyfile(TOP / "napari.yaml", TOP / "car_napari" / "napari.yaml")
            return
        package = Path(self.build_lib) / "car_napari"
        shutil.copyfile(TOP / "napari.yaml", package / "napari.yaml")
        target = package / "_resources"
        target.mkdir(exist_ok=True)
        for pattern in SHIPPED_RESOURCES:
            for path in (TOP / "resources").glob(pattern):
                if path.name not in UNSHIPPED_RESOURCES:
                    shutil.copyfile(path, target / path.name)


setup(cmdclass={"build_py": BuildWithManifest})
