"""Finding shader sources (GLSL, OpenCL C) in a checkout or an installed wheel."""
from __future__ import annotations

import os
import sys
from pathlib import Path


def shader_dirs() -> list[Path]:
    dirs = []
    if os.environ.get("GRAPHKIT_SHADERS"):
        dirs.append(Path(os.environ["GRAPHKIT_SHADERS"]))
    dirs.append(Path(__file__).resolve().parents[1] / "shaders")  # a checkout / editable install
    dirs.append(Path(sys.prefix) / "share" / "relightkit" / "shaders")  # an installed wheel
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
