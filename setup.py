"""The package's build (setuptools; the rest is in pyproject.toml), with the web dashboard's
page bundled first when it is not built yet: ``pip wheel .`` then carries it. Without npm, or
if the bundle cannot be built, the package builds without it and says so (``usbmotion web``
then serves its API and says the page is not built)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
FRONTEND = HERE / "src" / "usbmotion" / "web" / "frontend"
BUNDLE = HERE / "src" / "usbmotion" / "web" / "static" / "dist" / "app.js"


def build_page() -> None:
    """npm ci and esbuild in the front end's folder, unless the bundle is there."""
    if BUNDLE.is_file() or not FRONTEND.is_dir():
        return
    if shutil.which("npm") is None or shutil.which("node") is None:
        sys.stderr.write("usbmotion: no npm, so the web dashboard's page is not built\n")
        return
    try:
        subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--loglevel=error"],
                       cwd=FRONTEND, check=True)
        subprocess.run(["node", "build.mjs"], cwd=FRONTEND, check=True)
    except (OSError, subprocess.CalledProcessError) as error:
        sys.stderr.write(f"usbmotion: the web dashboard's page was not built: {error}\n")


class BuildWithPage(build_py):
    """setuptools' build_py, the page bundled first."""

    def run(self) -> None:
        build_page()
        super().run()


setup(cmdclass={"build_py": BuildWithPage})
