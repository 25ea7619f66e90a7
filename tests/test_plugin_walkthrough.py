"""docs/plugins.md runs: its marked code blocks (```lang file=PATH) make a plugin in a temp folder,
registered without pip (GRAPHKIT_PLUGINS=my_plugin, the folder on PYTHONPATH), and the commands
the page shows give the outputs it shows:

* ``graphkit nodes Gain`` prints exactly the page's output;
* ``graphkit conform my_plugin`` passes, printing the page's output: the opencl backend agrees
  with the numpy reference on pocl (an unavailable OpenCL fails this test with the reason, it is
  not skipped) and every declared constraint is refused naming its port; so does the page's
  own pytest file for the plugin;
* ``graphkit run gain.yaml`` writes what the page says, and a one-channel photo is refused
  with exit 2 naming the port, with the page's message.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from conftest import ROOT, engine_env, graphkit, read_exr

PAGE = ROOT / "docs" / "plugins.md"
BLOCK = re.compile(r"^```(\w+)(?: file=(\S+))?\n(.*?)^```\n", re.S | re.M)


def blocks() -> list[tuple[str, str | None, str]]:
    """(language, file or None, text) of every fenced code block of the page."""
    return [(m[1], m[2], m[3]) for m in BLOCK.finditer(PAGE.read_text())]


def shown(command: str) -> str:
    """The output the page shows for ``$ command`` (a ```console block: the lines after it, up
    to the next "$ " line)."""
    for lang, _, text in blocks():
        if lang == "console" and f"$ {command}\n" in text:
            rest = text.split(f"$ {command}\n", 1)[1]
            return rest.split("\n$ ", 1)[0]
    raise AssertionError(f"docs/plugins.md shows no `$ {command}`")


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    """The page's files written into a folder; the environment that registers the plugin."""
    root = tmp_path_factory.mktemp("walkthrough")
    files = [(f, text) for _, f, text in blocks() if f]
    assert {"pyproject.toml", "my_plugin/__init__.py", "my_plugin/gain.py", "my_plugin/gain.cl",
            "my_plugin/gain_opencl.py", "gain.yaml", "tests/test_gain.py"} <= {f for f, _ in files}
    for name, text in files:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    env = engine_env({"GRAPHKIT_PLUGINS": "my_plugin"})
    env["PYTHONPATH"] = f"{root}:{env['PYTHONPATH']}"
    return root, env


def test_entry_points_name_the_registered_tables(plugin):
    root, _ = plugin
    eps = tomllib.loads((root / "pyproject.toml").read_text())["project"]["entry-points"]
    assert eps["graphkit.nodes"] == {"gain": "my_plugin:NODES"}
    assert eps["graphkit.backends"] == {"gain": "my_plugin:BACKENDS"}


def test_nodes_shows_the_declarations(plugin):
    root, env = plugin
    r = graphkit("nodes", "Gain", env=env, cwd=root)
    assert r.returncode == 0, r.stderr
    assert r.stdout == shown("graphkit nodes Gain")


def test_conform_passes_on_opencl(plugin):
    """Every backend and constraint conforms; OpenCL must be there (pocl: `make sysdeps`)."""
    root, env = plugin
    r = graphkit("conform", "my_plugin", env=env, cwd=root, timeout=300)
    assert r.returncode == 0, f"graphkit conform my_plugin failed (exit {r.returncode}):\n{r.stdout}{r.stderr}"
    assert r.stdout == shown("graphkit conform my_plugin")
    assert "Gain/opencl" in r.stdout and "port 'mask'" in r.stdout


def test_the_plugins_own_test_passes(plugin):
    root, env = plugin
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_gain.py"],
                       cwd=root, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


def test_run_gives_the_documented_outputs_and_refuses_a_grey_photo(plugin, tmp_path):
    root, env = plugin
    r = graphkit("run", "gain.yaml", "--out", tmp_path / "out", "--cache", tmp_path / "cache",
                 env=env, cwd=root, timeout=300)
    assert r.returncode == 0, r.stderr
    photo, brighter = read_exr(tmp_path / "out" / "photo.exr"), read_exr(tmp_path / "out" / "brighter.exr")
    assert photo.shape == (512, 512, 3)
    np.testing.assert_array_equal(brighter, 2 * photo)  # stops: 1 doubles every value exactly
    brighter_node = json.loads((tmp_path / "out" / "manifest.json").read_text())["nodes"]["brighter"]
    assert brighter_node["backend"] == "opencl", brighter_node  # pinned: no fallback to numpy
    assert brighter_node["backend_version"].startswith("1 (") and "no OpenCL device" not in brighter_node["backend_version"]

    grey = oiio.ImageBuf(oiio.ImageSpec(8, 8, 1, "float"))
    assert grey.write(str(tmp_path / "grey.exr"))
    r = graphkit("run", "gain.yaml", "--set", f"photo={tmp_path / 'grey.exr'}", "--out", tmp_path / "o2",
                 "--cache", tmp_path / "cache", env=env, cwd=root)
    assert r.returncode == 2, r.stderr
    refusal = [ln for ln in r.stderr.splitlines() if "bad input" in ln]
    assert refusal == ["graphkit: bad input: node 'brighter' (Gain), port 'image': needs 3 channels, got 1"], r.stderr
    assert refusal[0] in shown("graphkit run gain.yaml --set photo=grey.exr").splitlines()
    assert "Traceback" not in r.stderr


def test_a_missing_plugin_kernel_makes_the_backend_unavailable(plugin, monkeypatch):
    from graphkit_opencl.runtime import Unavailable, runtime

    monkeypatch.syspath_prepend(str(plugin[0]))
    with pytest.raises(Unavailable, match="kernel nope.cl not found in package my_plugin"):
        runtime().program("my_plugin:nope.cl")
    with pytest.raises(Unavailable, match="No module named 'no_such_plugin'"):
        runtime().program("no_such_plugin:gain.cl")
    assert runtime().program("my_plugin:gain.cl") is not None
