"""The same graph on a real Dask scheduler and workers (loopback) gives the same bytes."""
import json

from conftest import graphkit

G = """\
graphkit: 1
name: dasky
nodes:
  a: {type: Slow, params: {seconds: 0.0, megabytes: 1, seed: 1}}
  b: {type: Slow, params: {seconds: 0.0, megabytes: 1, seed: 2}}
  c: {type: Add, inputs: {a: a.out, b: b.out}, params: {offset: 0.5}}
  s: {type: Sum, inputs: {xs: [a.out, c.out, b.out]}}
  photo: {type: LoadImage, params: {path: "builtin:astronaut"}}
  r: {type: RatioImage, inputs: {a: photo.image, b: photo.image}}
  save: {type: SaveImage, inputs: {image: r.ratio}, params: {path: r.exr}}
outputs: {s: s.out, img: save.file}
"""


def test_dask_matches_local(tmp_path, write):
    g = write("g.yaml", G)
    r = graphkit("run", g, "--executor", "dask", "--jobs", "2", "--cache", tmp_path / "dc", "--out", tmp_path / "d",
                 timeout=180)
    assert r.returncode == 0, r.stderr
    r = graphkit("run", g, "--cache", tmp_path / "lc", "--out", tmp_path / "l")
    assert r.returncode == 0, r.stderr
    for f in ("s.npy", "r.exr"):
        assert (tmp_path / "d" / f).read_bytes() == (tmp_path / "l" / f).read_bytes(), f
    md = json.loads((tmp_path / "d" / "manifest.json").read_text())
    ml = json.loads((tmp_path / "l" / "manifest.json").read_text())
    assert md["executor"] == "dask" and ml["executor"] == "local"
    assert {n: v["key"] for n, v in md["nodes"].items()} == {n: v["key"] for n, v in ml["nodes"].items()}
    # a second Dask run finds everything in the cache the workers wrote
    r = graphkit("run", g, "--executor", "dask", "--jobs", "2", "--cache", tmp_path / "dc", "--out", tmp_path / "d2",
                 timeout=180)
    assert r.returncode == 0 and "0 computed, 7 cached" in r.stderr, r.stderr


def test_dask_reports_node_failures(tmp_path, write):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n  f: {type: Fail, inputs: {x: c.out}}\n")
    r = graphkit("run", g, "--executor", "dask", "--jobs", "1", "--cache", tmp_path / "c", "--out", tmp_path / "o",
                 timeout=180)
    assert r.returncode == 1, r.stderr
    assert "node 'f' (Fail) failed: ZeroDivisionError: boom" in r.stderr and "Traceback" not in r.stderr
