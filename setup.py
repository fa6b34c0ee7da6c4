"""Build hook: ship the renderer's builtin scenes as package data.

The scene specifications live in ``data/synthetic/`` at the top of the
repository (with the other data); a wheel carries a copy as
``vpr/render/scenes/*.json``, which :mod:`vpr.render.spec` finds with
:mod:`importlib.resources`. Everything else is configured in pyproject.toml.
"""
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

SCENES = Path(__file__).resolve().parent / "data" / "synthetic"


class BuildPyWithScenes(build_py):
    def run(self):
        super().run()
        dest = Path(self.build_lib) / "vpr" / "render" / "scenes"
        self.mkpath(str(dest))
        for src in sorted(SCENES.glob("*.json")):
            self.copy_file(str(src), str(dest / src.name))

    def get_outputs(self, include_bytecode=True):
        dest = Path(self.build_lib) / "vpr" / "render" / "scenes"
        return super().get_outputs(include_bytecode) + [str(dest / p.name) for p in sorted(SCENES.glob("*.json"))]


setup(cmdclass={"build_py": BuildPyWithScenes})
