"""The part of the package layout that pyproject.toml cannot say: ``shaders/`` at the top of the
checkout (GLSL and OpenCL C, beside the plugins that use them) is installed as the package
``graphkit.shaders``, so an installed wheel finds its shaders with importlib.resources wherever
it is installed (a venv, ``pip install --target``).  Data folders (``nodes/*/data``) are
namespace packages, so their files are package data (pyproject.toml lists the extensions).
Everything else is in pyproject.toml."""
import os

from setuptools import find_namespace_packages, setup

SKIP = ["*.__pycache__", "*.__pycache__.*", "*.egg-info"]
SHADERS = ["graphkit.shaders"] + [
    f"graphkit.shaders.{d}" for d in sorted(os.listdir("shaders"))
    if os.path.isdir(os.path.join("shaders", d)) and d != "__pycache__"
]

setup(
    packages=find_namespace_packages(include=["graphkit", "graphkit.*", "nodes", "nodes.*"], exclude=SKIP) + SHADERS,
    package_dir={"graphkit.shaders": "shaders"},
)
