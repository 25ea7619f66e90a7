import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SUPPORT = Path(__file__).resolve().parent / "support"
sys.path.insert(0, str(SUPPORT))


def engine_env(extra: dict | None = None) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(SUPPORT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["GRAPHKIT_PLUGINS"] = "enginenodes"
    env.pop("GRAPHKIT_TRACEBACK", None)
    env.update(extra or {})
    return env


def graphkit(*args, env=None, cwd=None, timeout=120, **kw) -> subprocess.CompletedProcess:
    """Run the graphkit CLI in a fresh interpreter (as a user would)."""
    return subprocess.run([sys.executable, "-m", "graphkit", *map(str, args)], capture_output=True,
                          text=True, env=env or engine_env(), cwd=cwd, timeout=timeout, **kw)


def read_exr(path):
    """Pixels of an image file as float32 H×W×C, read with OpenImageIO."""
    import numpy as np
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    px = inp.read_image(0, 0, 0, inp.spec().nchannels, "float")
    inp.close()
    return np.asarray(px, np.float32)


@pytest.fixture
def engine_registry():
    """A registry with the built-in nodes and the engine test nodes."""
    import enginenodes

    from graphkit.registry import discover

    reg = discover()
    reg.add_provider("nodes", "tests", enginenodes)
    return reg


@pytest.fixture
def write(tmp_path):
    def _write(name: str, text: str) -> Path:
        p = tmp_path / name
        p.write_text(text)
        return p
    return _write
