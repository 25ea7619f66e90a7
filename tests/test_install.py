"""The wheel built from this checkout, installed into a fresh venv outside the checkout, runs
every graph in graphs/; it holds every data file, shader and licence; shaders and builtin data
are found after ``pip install --target`` too.

The venv gets relightkit and the plugins from their wheels (``--no-deps``, no index); their
dependencies (numpy, OpenImageIO, …, several hundred MB) come from the test venv through a
``.pth`` line naming its site-packages, which Python adds to sys.path after the new venv's own
site-packages without running the test venv's .pth files, so relightkit's editable install is
not active there.  The tests check that ``graphkit`` and ``nodes`` are imported from the new
venv.  Graphs costing minutes cold are cut to cheap outputs here (``CHEAP_OUTPUTS``);
``make wheel-check`` (GRAPHKIT_WHEEL_FULL=1) runs them whole.
"""
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = sorted(p.parent for p in (ROOT / "plugins").glob("*/pyproject.toml"))
# graph stem -> outputs run by make test (whole graph under GRAPHKIT_WHEEL_FULL=1)
CHEAP_OUTPUTS = {"room_relight": ["photo"],  # radiosity: ~3 min cold on 2 busy cores
                 "face_ring": ["relit/ring00"], "makeup_batch": ["made_up/astronaut"]}  # one instance of each sweep

pytestmark = pytest.mark.xdist_group("install")


def _clean_env() -> dict:
    """The environment without anything that would point Python at the checkout."""
    return {k: v for k, v in os.environ.items()
            if not k.startswith("GRAPHKIT_") and k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}


def _run(cmd, cwd, timeout=600, env=None):
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                       env=env or _clean_env())
    assert r.returncode == 0, f"{cmd}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


def _source_copy(dest: Path) -> Path:
    """The checkout's files (tracked, and new ones git does not ignore) copied to ``dest``: pip
    builds in the source tree, and setuptools' build/ there would keep files deleted since."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                             capture_output=True, check=True)
        names = [n for n in out.stdout.decode().split("\0") if n and (ROOT / n).is_file()]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: copy it whole
        shutil.copytree(ROOT, dest, ignore=shutil.ignore_patterns("build", ".venv", "*.egg-info", "__pycache__"))
        return dest
    for n in names:
        (dest / n).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / n, dest / n)
    return dest


@pytest.fixture(scope="session")  # built once even when xdist interleaves other modules
def wheels(tmp_path_factory):
    out = tmp_path_factory.mktemp("wheels")
    src = _source_copy(tmp_path_factory.mktemp("src") / "relightkit")
    # isolated builds: pip fetches setuptools once, then takes it from its cache
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "--disable-pip-version-check",
          "-w", out, src, *(src / p.relative_to(ROOT) for p in PLUGINS)], cwd=out)
    found = {p.name.split("-")[0]: p for p in out.glob("*.whl")}
    assert "relightkit" in found and len(found) == 1 + len(PLUGINS), found
    return found


@pytest.fixture(scope="session")  # built once even when xdist interleaves other modules
def venv(wheels, tmp_path_factory):
    home = tmp_path_factory.mktemp("venv")
    assert ROOT not in home.parents
    v = home / "v"
    _run([sys.executable, "-m", "venv", "--without-pip", v], cwd=home)
    py = v / "bin" / "python"
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=home).stdout.strip())
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "_test_venv_dependencies.pth").write_text("\n".join(sorted(deps)) + "\n")
    _run([sys.executable, "-m", "pip", "--python", py, "install", "-q", "--disable-pip-version-check",
          "--no-deps", "--no-index", *wheels.values()], cwd=home)
    return v


def test_installed_packages_come_from_the_new_venv(venv):
    code = ("import importlib.metadata as md, json, graphkit, nodes, nodes.io.images, graphkit_opencl;"
            "print(json.dumps({'graphkit': graphkit.__file__, 'nodes': nodes.__file__,"
            " 'images': nodes.io.images.__file__, 'opencl': graphkit_opencl.__file__,"
            " 'dist': str(md.distribution('relightkit').locate_file(''))}))")
    where = json.loads(_run([venv / "bin" / "python", "-c", code], cwd=venv.parent).stdout)
    for name, path in where.items():
        assert Path(path).resolve().is_relative_to(venv.resolve()), (name, path)
        assert not Path(path).resolve().is_relative_to(ROOT), (name, path)


def test_every_graph_runs_from_the_wheel(venv, tmp_path):
    graphs = tmp_path / "graphs"
    shutil.copytree(ROOT / "graphs", graphs)  # outside the checkout: nothing relative to it
    full = os.environ.get("GRAPHKIT_WHEEL_FULL") == "1"
    ran = []
    for g in sorted(graphs.glob("*.yaml")):
        out = tmp_path / "out" / g.stem
        cmd = [venv / "bin" / "graphkit", "run", g, "--cache", tmp_path / "cache", "--out", out, "-q", "--jobs", "2"]
        if not full:
            for o in CHEAP_OUTPUTS.get(g.stem, []):
                cmd += ["--output", o]
        _run(cmd, cwd=tmp_path, timeout=1200)
        manifest = json.loads((out / "manifest.json").read_text())
        files = [f for f in out.rglob("*") if f.is_file() and f.name != "manifest.json"]
        assert files and all(f.stat().st_size > 0 for f in files), (g.name, files)
        assert Path(manifest["graph"]) == g
        ran.append(g.stem)
    assert len(ran) >= 6, ran  # graphs/ as of this test's writing: blush … room_relight


def _tracked(prefixes) -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", "-z", *prefixes], cwd=ROOT, capture_output=True, check=True)
        names = [n for n in out.stdout.decode().split("\0") if n]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: what is on disk
        names = [str(p.relative_to(ROOT)) for pre in prefixes for p in (ROOT / pre).rglob("*")
                 if p.is_file() and "__pycache__" not in p.parts]
    return [n for n in names if (ROOT / n).is_file()]


def test_wheel_holds_every_file_and_licence(wheels):
    with zipfile.ZipFile(wheels["relightkit"]) as z:
        names = set(z.namelist())
    want = {n for n in _tracked(["graphkit", "nodes"])}
    want |= {"graphkit/" + n for n in _tracked(["shaders"])}
    missing = sorted(want - names)
    assert not missing, f"the wheel lacks {missing}: add their extension to [tool.setuptools.package-data]"
    for must in ("nodes/loscos/data/cornell2.exr", "nodes/paris/data/sample_capture/photo.exr",
                 "nodes/paris/data/sample_capture/probe.exr", "nodes/paris/data/sample_capture/mesh.ply",
                 "graphkit/shaders/opencl/ratio.cl"):
        assert must in names
    lic = {n.split("licenses/", 1)[1] for n in names if ".dist-info/licenses/" in n}
    assert {"LICENSE", "NOTICE"} <= lic and any(n.startswith("LICENSES/BSD-3-Clause") for n in lic), lic
    notice = (ROOT / "NOTICE").read_text()
    for n in sorted(lic):  # every licence text shipped is named by the notices
        if n.startswith("LICENSES/"):
            assert n in notice, n


def test_shaders_and_builtins_after_pip_install_target(wheels, tmp_path):
    target = tmp_path / "target"
    _run([sys.executable, "-m", "pip", "install", "-q", "--disable-pip-version-check", "--no-deps",
          "--no-index", "--target", target, wheels["relightkit"]], cwd=tmp_path)
    # -S: no site-packages at all (no editable install of the checkout); only the target folder
    code = ("import sys; sys.path.insert(0, sys.argv[1]);"
            "from graphkit.resources import shader_path; from nodes.io.builtin import builtin_path;"
            "print(shader_path('opencl/ratio.cl')); print(shader_path('glsl/shade.frag'));"
            "print(builtin_path('builtin:sample_capture/photo.exr'))")
    r = _run([sys.executable, "-S", "-c", code, target], cwd=tmp_path)
    paths = r.stdout.split()
    assert len(paths) == 3 and all(Path(p).is_file() and Path(p).is_relative_to(target) for p in paths), paths
