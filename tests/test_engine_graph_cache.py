"""A graph file may name its cache (issue 29, item 5): ``cache: {url, options}``, with --cache
replacing it and --cache-option / GRAPHKIT_CACHE_OPTIONS adding to its options; the options a
file may hold say only where the cache is (never credentials: a graph file is shared and
committed); `graphkit cache info G.yaml` shows the setting in effect and where it comes from."""
import json

from conftest import engine_env, graphkit

G = """\
graphkit: 1
name: cached
cache:
  url: {url}
nodes:
  a: {{type: Const, params: {{value: 1.0, size: 4}}}}
outputs: {{a: a.out}}
"""


def test_a_run_uses_the_cache_its_graph_file_names(write, tmp_path):
    g = write("g.yaml", G.format(url="shared-cache"))  # a folder, relative to the graph file
    (tmp_path / "elsewhere").mkdir()
    r = graphkit("run", g, "--out", tmp_path / "o", env=engine_env({"GRAPHKIT_CACHE": str(tmp_path / "env")}),
                 cwd=tmp_path / "elsewhere")
    assert r.returncode == 0, r.stderr
    assert (g.parent / "shared-cache" / "format-1").exists() and not (tmp_path / "env").exists()
    info = graphkit("cache", "info", g, env=engine_env())
    assert info.returncode == 0 and "setting: the graph file" in info.stdout, info.stdout
    assert f"cache: {g.parent / 'shared-cache'}" in info.stdout
    status = graphkit("status", g, env=engine_env())  # the same cache: all cached
    assert status.returncode == 0 and "0 would run, 1 cached" in status.stdout, status.stdout


def test_cache_replaces_the_graph_files_setting(write, tmp_path):
    g = write("g.yaml", G.format(url="s3://nowhere-bucket/x"))
    r = graphkit("run", g, "--cache", tmp_path / "mine", "--out", tmp_path / "o", env=engine_env())
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "mine" / "format-1").exists()
    info = graphkit("cache", "info", g, "--cache", tmp_path / "mine", env=engine_env())
    assert "setting: --cache" in info.stdout and f"cache: {tmp_path / 'mine'}" in info.stdout, info.stdout


def test_the_graph_files_options_go_under_the_environments(write):
    g = write("g.yaml", G.format(url="memory://graph-opts").replace(
        "  url: memory://graph-opts\n", "  url: memory://graph-opts\n  options: {anon: true, region_name: eu-west-1}\n"))
    env = engine_env({"GRAPHKIT_CACHE_OPTIONS": json.dumps({"anon": False})})
    info = graphkit("cache", "info", g, env=env)
    assert info.returncode == 0, info.stderr
    (opts,) = [json.loads(line.split(": ", 1)[1]) for line in info.stdout.splitlines() if line.startswith("options:")]
    assert opts == {"anon": False, "client_kwargs": {"region_name": "eu-west-1"}}


def test_a_graph_file_names_no_credentials_and_no_unknown_key(write):
    g = write("bad.yaml", """\
graphkit: 1
name: bad
cache:
  url: s3://b/x
  optoins: {}
  options: {secret: s3cr3t, endpoint_url: "http://127.0.0.1:9"}
nodes:
  a: {type: Const, params: {value: 1.0, size: 4}}
outputs: {a: a.out}
""")
    r = graphkit("run", g, env=engine_env())
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{g}:5:3: error: unknown cache key 'optoins'; did you mean 'options'?" in r.stderr, r.stderr
    assert f"{g}:6:13: error: cache option 'secret' cannot be set in a graph file" in r.stderr
    assert "s3cr3t" not in r.stderr
    for bad, said in (("cache: s3://b/x", "'cache' must be a mapping"), ("cache: {url: 3}", "'url' must be")):
        b = write("b2.yaml", f"graphkit: 1\nname: b2\n{bad}\nnodes: {{}}\noutputs: {{}}\n")
        r = graphkit("validate", b, env=engine_env())
        assert r.returncode == 2 and f"{b}:3:" in r.stderr and said in r.stderr, r.stderr
