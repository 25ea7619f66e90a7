"""The front door: quickstart does what it says, `nodes` shows types and defaults as written,
--version, one summary line for a cached run, GRAPHKIT_PLUGINS dicts, the public conformance
harness, and no third-party log lines on the terminal."""
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from conftest import ROOT, engine_env, graphkit, read_exr


def test_quickstart_divides_the_photo_by_a_smoothed_copy(tmp_path):
    """Its comment: the photo divided by a smoothed copy of itself (checked against scipy)."""
    import colour
    import scipy.ndimage
    import skimage.data

    from graphkit import run_graph

    text = (ROOT / "graphs" / "quickstart.yaml").read_text()
    assert "divided by a smoothed copy of itself" in text
    run_graph(ROOT / "graphs" / "quickstart.yaml", cache=tmp_path / "c", out=tmp_path / "o")
    photo = colour.cctf_decoding(skimage.data.astronaut() / 255.0, "sRGB")
    smooth = np.stack([scipy.ndimage.gaussian_filter(photo[:, :, c], 6.0, mode="reflect", truncate=3.0)
                       for c in range(3)], axis=2)
    want = photo / np.maximum(smooth, 1e-4)
    got = read_exr(tmp_path / "o" / "detail.exr")
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=2e-3, atol=2e-4)  # half-float EXR
    assert np.std(got) > 0.05  # a detail texture, not photo / photo = 1


def test_nodes_shows_types_and_real_defaults(capsys):
    from graphkit.cli import main

    assert main(["nodes", "RatioImage"]) == 0
    out = capsys.readouterr().out
    assert "  eps: float = 0.0001" in out and "<class" not in out
    assert main(["nodes", "LoadImage", "--json"]) == 0
    params = json.loads(capsys.readouterr().out)[0]["params"]
    assert params["path"] == {"type": "InputFile", "required": True,
                              "doc": "image file, relative to the graph file, or builtin:NAME"}
    assert params["drop_alpha"]["default"] is True and params["colorspace"]["default"] == "auto"
    assert params["colorspace"]["type"] == '"auto" | "srgb" | "linear"'
    assert main(["nodes", "ContactSheet", "--json"]) == 0
    params = json.loads(capsys.readouterr().out)[0]["params"]
    assert params["labels"]["default"] == [] and params["labels"]["type"] == "list[str]"
    assert params["cell_width"]["default"] == 256


def test_version(capsys):
    from graphkit import __version__
    from graphkit.cli import main

    with pytest.raises(SystemExit) as ei:
        main(["--version"])
    assert ei.value.code == 0
    assert capsys.readouterr().out.startswith(f"graphkit {__version__} (relightkit ")


def test_a_fully_cached_run_prints_one_line(tmp_path, write):
    g = write("g.yaml", "graphkit: 1\nname: one\nnodes:\n  a: {type: Const}\n  b: {type: Add, inputs: {a: a.out}}\n")
    args = ["run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o"]
    r = graphkit(*args)
    assert r.returncode == 0 and len(r.stderr.splitlines()) == 3, r.stderr  # two computed + summary
    r = graphkit(*args)
    assert r.returncode == 0 and r.stdout == ""
    assert r.stderr.splitlines() == [r.stderr.strip()] and r.stderr.startswith("one: 0 computed, 2 cached, ")
    r = graphkit(*args, "-v")
    lines = r.stderr.splitlines()
    assert len(lines) == 3 and "cached a (Const)" in lines[0] and "cached b (Add)" in lines[1]


PLUGIN = {
    "lazyplug.py": """
        NODES = {"Twice": "lazyplug_impl:Twice"}
    """,
    "goodplug.py": 'BACKENDS = {"Twice/fast": "lazyplug_impl:TwiceFast"}\n',
    "badplug.py": 'BACKENDS = {"Twice/wrong": "lazyplug_impl:TwiceWrong"}\n',
    "absentplug.py": 'BACKENDS = {"Twice/gpu": "lazyplug_impl:TwiceGpu"}\n',
    "lazyplug_impl.py": """
        import os
        import numpy as np
        from graphkit import Array, Backend, Node

        open(os.environ["LAZY_MARK"], "a").write("imported\\n")

        class Twice(Node):
            \"\"\"x * 2\"\"\"
            inputs = {"x": Array}
            outputs = {"out": Array}
            tolerance = {"rtol": 1e-6, "atol": 1e-9}

            @classmethod
            def examples(cls):
                return [({}, {"x": np.linspace(-1, 1, 9)}), ({}, {"x": np.array([1e6, 0.0])})]

            def compute(self, x):
                return x * 2

        class TwiceFast(Backend):
            node, name = "Twice", "fast"
            def compute(self, x):
                return x + x

        class TwiceWrong(Backend):
            node, name = "Twice", "wrong"
            def compute(self, x):
                return x * 2 + 1e-3

        class TwiceGpu(Backend):
            node, name = "Twice", "gpu"
            @classmethod
            def available(cls):
                return False
            @classmethod
            def why_unavailable(cls):
                return "no GPU here"
            def compute(self, x):
                return x * 2
    """,
}


@pytest.fixture
def plugin_dir(tmp_path):
    d = tmp_path / "plug"
    d.mkdir()
    for name, text in PLUGIN.items():
        (d / name).write_text(textwrap.dedent(text))
    return d


def plugin_env(d, mark):
    env = engine_env({"GRAPHKIT_PLUGINS": "enginenodes,lazyplug,goodplug,badplug,absentplug", "LAZY_MARK": str(mark)})
    env["PYTHONPATH"] = f"{d}:{env['PYTHONPATH']}"
    return env


def test_graphkit_plugins_loads_nodes_and_backends_dicts_lazily(tmp_path, write, plugin_dir):
    mark = tmp_path / "mark"
    env = plugin_env(plugin_dir, mark)
    r = graphkit("validate", write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n"), env=env)
    assert r.returncode == 0, r.stderr
    assert not mark.exists()  # not imported: the graph does not use it
    r = graphkit("nodes", "Twice", env=env)
    assert r.returncode == 0, r.stderr
    assert "from GRAPHKIT_PLUGINS:lazyplug" in r.stdout and "backends: numpy, fast, gpu, wrong" in r.stdout, r.stdout
    assert mark.exists()


def test_conform_checks_a_plugin_s_backends(tmp_path, plugin_dir, monkeypatch):
    from graphkit.conformance import check_backends
    from graphkit.registry import discover

    monkeypatch.syspath_prepend(str(plugin_dir))
    env = plugin_env(plugin_dir, tmp_path / "mark")
    monkeypatch.setenv("GRAPHKIT_PLUGINS", env["GRAPHKIT_PLUGINS"])
    monkeypatch.setenv("LAZY_MARK", env["LAZY_MARK"])
    reg = discover()
    good = check_backends(reg, plugin="goodplug")
    assert [(f.backend, f.case, f.ok) for f in good] == [("fast", 0, True), ("fast", 1, True)]
    bad = check_backends(reg, plugin="badplug")
    assert [f.ok for f in bad] == [False, False] and "outside rtol=1e-06, atol=1e-09" in bad[0].message
    absent = check_backends(reg, plugin="absentplug")
    assert [(f.ok, f.checked, f.message) for f in absent] == [(False, False, "not available: no GPU here")]

    r = graphkit("conform", "badplug", env=env)
    assert r.returncode == 1 and "FAIL  Twice/wrong example 0: output 'out': array 0: max abs difference 0.001" in r.stdout
    r = graphkit("conform", "absentplug", env=env)
    assert r.returncode == 2 and "skip  Twice/gpu: not available: no GPU here" in r.stdout, r.stdout
    r = graphkit("conform", "nosuchplug", env=env)
    assert r.returncode == 2 and "no backends from plugin 'nosuchplug'" in r.stderr


THIRD_PARTY = [
    "INFO: Created TensorFlow Lite XNNPACK delegate for CPU.",
    "WARNING: All log messages before absl::InitializeLog() is called are written to STDERR",
    "W0000 00:00:1796154959.376830   11895 inference_feedback_manager.cc:114] Feedback manager requires a model",
    "I1201 20:07:12.123456  4242 gl_context.cc:369] GL version: 3.2",
]


def test_native_log_lines_are_dropped_and_ours_kept(tmp_path):
    code = textwrap.dedent(f"""
        import os, sys, threading
        from graphkit_mediapipe.quiet import native_logs_filtered
        print("before", file=sys.stderr, flush=True)
        with native_logs_filtered():
            for line in {THIRD_PARTY!r}:
                os.write(2, (line + "\\n").encode())
            os.write(2, b"ours: kept\\n")
            t = threading.Thread(target=lambda: print("from a thread", file=sys.stderr, flush=True))
            t.start(); t.join()
            with native_logs_filtered():
                os.write(2, b"nested ok\\n")
        print("after", file=sys.stderr, flush=True)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env=engine_env({"GRAPHKIT_NATIVE_LOG": str(tmp_path / "native.log")}))
    assert r.returncode == 0, r.stderr
    assert r.stderr.splitlines() == ["before", "ours: kept", "from a thread", "nested ok", "after"]
    assert (tmp_path / "native.log").read_text().splitlines() == THIRD_PARTY


def test_facemesh_run_prints_no_third_party_lines(tmp_path, write):
    g = write("fm.yaml", "graphkit: 1\nnodes:\n  photo: {type: LoadImage, params: {path: 'builtin:astronaut'}}\n"
                         "  face: {type: FaceMesh, inputs: {image: photo.image}}\noutputs: [face.landmarks]\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o", timeout=240)
    assert r.returncode == 0, r.stderr
    assert r.stderr.splitlines()[-1].startswith("fm: 2 computed"), r.stderr
    assert len(r.stderr.splitlines()) == 3, r.stderr  # two node lines and the summary, nothing else
    for bad in ("TensorFlow", "absl", "W0000", "GetPrototype", "inference_feedback"):
        assert bad not in r.stderr
