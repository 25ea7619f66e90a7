"""Bad input: one clear message naming the file/node/port, exit 2 (1 for a node failure),
no traceback, nothing partial in the cache or the output folder."""
import os
import resource
import shutil
import subprocess

import numpy as np
import pytest

from conftest import graphkit
from graphkit.store import Store


def load_ratio_graph(a: str, b: str) -> str:
    return f"""\
graphkit: 1
name: bad
nodes:
  a: {{type: LoadImage, params: {{path: "{a}"}}}}
  b: {{type: LoadImage, params: {{path: "{b}"}}}}
  ratio: {{type: RatioImage, inputs: {{a: a.image, b: b.image}}}}
  save: {{type: SaveImage, inputs: {{image: ratio.ratio}}, params: {{path: r.exr}}}}
outputs: {{r: save.file}}
"""


def write_exr(path, px):
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(px.shape[1], px.shape[0], px.shape[2], "float"))
    out.write_image(px.astype(np.float32))
    out.close()


def check_clean_failure(r, code, *needles, out=None, cache=None):
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    for n in needles:
        assert n in r.stderr, (n, r.stderr)
    if out is not None:
        assert not out.exists() or not any(out.iterdir()), list(out.iterdir())
    if cache is not None:
        assert Store(cache).open().verify() == []


def test_unreadable_image(tmp_path, write):
    (tmp_path / "junk.png").write_bytes(b"\x89PNG not really")
    g = write("g.yaml", load_ratio_graph("junk.png", "builtin:astronaut"))
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    check_clean_failure(r, 2, "node 'a' (LoadImage), port 'path'", "cannot read image", out=tmp_path / "o",
                        cache=tmp_path / "c")


def test_nan_in_image(tmp_path, write):
    px = np.ones((8, 8, 3), np.float32)
    px[3, 4, 1] = np.nan
    px[5, 5, 0] = np.inf
    write_exr(tmp_path / "nan.exr", px)
    g = write("g.yaml", load_ratio_graph("nan.exr", "nan.exr"))
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    check_clean_failure(r, 2, "port 'path'", "1 NaN and 1 Inf values", out=tmp_path / "o")


def test_mismatched_sizes_at_ratio(tmp_path, write):
    write_exr(tmp_path / "small.exr", np.ones((16, 16, 3), np.float32))
    g = write("g.yaml", load_ratio_graph("builtin:astronaut", "small.exr"))
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    check_clean_failure(r, 2, "node 'ratio' (RatioImage), port 'b'", "image sizes differ: a is 512×512×3, b is 16×16×3",
                        out=tmp_path / "o", cache=tmp_path / "c")


def test_node_failure_exit_1(tmp_path, write):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n  f: {type: Fail, inputs: {x: c.out}}\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    check_clean_failure(r, 1, "node 'f' (Fail) failed: ZeroDivisionError: boom", out=tmp_path / "o",
                        cache=tmp_path / "c")
    g = write("w.yaml", "graphkit: 1\nnodes:\n  w: {type: WrongType}\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    check_clean_failure(r, 1, "node 'w' (WrongType) failed", "expected an Image, got ndarray")


def test_full_cache(tmp_path, write):
    """A file-size limit makes the disk 'full' for the run: clean exit 2, no corrupt entry."""
    g = write("g.yaml", "graphkit: 1\nnodes:\n  s: {type: Slow, params: {seconds: 0, megabytes: 4}}\n")
    cache = tmp_path / "c"
    Store(cache).open()

    def limit():
        import signal

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (1_000_000, 1_000_000))

    r = graphkit("run", g, "--cache", cache, "--out", tmp_path / "o", preexec_fn=limit)
    check_clean_failure(r, 2, "cannot write a cache object", out=tmp_path / "o", cache=cache)
    assert list((cache / "tmp").iterdir()) == []  # the temp file was removed
    assert list((cache / "keys").rglob("*.json")) == []


def test_read_only_cache(tmp_path, write):
    cache = tmp_path / "ro"
    cache.mkdir()
    if os.geteuid() == 0:
        if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(cache)]).returncode != 0:
            pytest.skip(reason="running as root without chattr +i: cannot make a folder read-only")
    else:
        cache.chmod(0o500)
    try:
        g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n")
        r = graphkit("run", g, "--cache", cache, "--out", tmp_path / "o")
        check_clean_failure(r, 2, f"cache {cache}: cannot create the cache folder", out=tmp_path / "o")
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(cache)])
        else:
            cache.chmod(0o700)


def test_missing_graph_and_bad_set(tmp_path, write):
    r = graphkit("run", tmp_path / "none.yaml")
    check_clean_failure(r, 2, "graph file not found")
    g = write("g.yaml", "graphkit: 1\nparams: {x: 1}\nnodes:\n  c: {type: Const, params: {value: '${params.x}'}}\n")
    r = graphkit("run", g, "--set", "y=2", "--cache", tmp_path / "c")
    check_clean_failure(r, 2, "--set y: the graph has no param 'y'")
    r = graphkit("run", g, "--set", "x=[1,", "--cache", tmp_path / "c")
    check_clean_failure(r, 2, "--set x: cannot parse value")
    r = graphkit("run", g, "--set", "x=abc", "--cache", tmp_path / "c")
    check_clean_failure(r, 2, "param 'value': Input should be a valid number")
