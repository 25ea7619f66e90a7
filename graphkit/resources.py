"""Finding shader sources (GLSL, OpenCL C) in an installed wheel or a checkout.

``shaders/`` at the top of the checkout is installed as the package ``graphkit.shaders``
(setup.py), so an installed graphkit finds its shaders relative to its own package with
importlib.resources, as trimesh finds its resources: in a venv, a user site, or a
``pip install --target`` folder alike, never under ``sys.prefix``.  In a checkout (and an
editable install) they are the checkout's ``shaders/``.  ``$GRAPHKIT_SHADERS`` comes first.
"""
from __future__ import annotations

import os
from pathlib import Path


def shader_dirs() -> list[Path]:
    dirs = []
    if os.environ.get("GRAPHKIT_SHADERS"):
        dirs.append(Path(os.environ["GRAPHKIT_SHADERS"]))
    from importlib.resources import files

    packaged = files("graphkit").joinpath("shaders")  # an installed wheel
    if isinstance(packaged, Path) and packaged.is_dir():
        dirs.append(packaged)
    dirs.append(Path(__file__).resolve().parents[1] / "shaders")  # a checkout / editable install
    return dirs


def shader_path(rel: str) -> Path:
    """Path of ``shaders/<rel>`` (e.g. ``opencl/ratio.cl``); FileNotFoundError lists where it looked."""
    for d in shader_dirs():
        p = d / rel
        if p.is_file():
            return p
    raise FileNotFoundError(f"shader {rel} not found in " + ", ".join(str(d) for d in shader_dirs()))


def shader_source(rel: str) -> str:
    return shader_path(rel).read_text()
