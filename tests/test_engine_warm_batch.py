"""Warm runs on an object store read their records in batches (issue 29, item 3): the records the
last run's notes name all at once, up front (executor.read_ahead); without notes, a whole
generation of the graph at once (the scheduling thread looks up every ready node together and
the store sends their reads with fsspec's multi-path cat); a folder reads each record as before."""
from graphkit import run_graph
from graphkit.store import FsspecFS, LocalFS

G = """\
graphkit: 1
name: wide
nodes:
""" + "".join(f"  s{i}: {{type: Const, params: {{value: {i}.0, size: 10}}}}\n" for i in range(6)) + \
    "".join(f"  a{i}: {{type: Add, inputs: {{a: s{i}.out}}, params: {{offset: 1}}}}\n" for i in range(6)) + """\
outputs: {a0: a0.out}
"""


def _count_batches(monkeypatch, cls):
    batches = []
    real = cls.read_many

    def read_many(self, rels):
        batches.append(sorted(r.split("/", 1)[0] for r in rels))
        return real(self, rels)
    monkeypatch.setattr(cls, "read_many", read_many)
    return batches


def test_a_warm_run_reads_its_records_in_one_batch(write, engine_registry, monkeypatch, tmp_path):
    g = write("wide.yaml", G.replace("outputs: {a0: a0.out}", "outputs: {" + ", ".join(
        f"a{i}: a{i}.out" for i in range(6)) + "}"))
    cold = run_graph(g, cache="memory://warm-batch", registry=engine_registry, jobs=2)
    assert len(cold.computed) == 12
    batches = _count_batches(monkeypatch, FsspecFS)
    warm = run_graph(g, cache="memory://warm-batch", out=tmp_path / "out", registry=engine_registry, jobs=2)
    assert warm.computed == [] and len(warm.cached) == 12
    records = [b for b in batches if b[0] == "keys"]
    assert records == [["keys"] * 12], batches  # every record the last run's notes name, together
    assert ["objects"] * 6 in batches  # the six exported values, read together


def test_without_notes_a_warm_run_reads_each_generation_in_one_batch(write, engine_registry, monkeypatch,
                                                                      tmp_path):
    from graphkit import executor

    g = write("wide.yaml", G.replace("outputs: {a0: a0.out}", "outputs: {" + ", ".join(
        f"a{i}: a{i}.out" for i in range(6)) + "}"))
    run_graph(g, cache="memory://warm-batch-gen", registry=engine_registry, jobs=2)
    monkeypatch.setattr(executor, "read_ahead", lambda session, nodes: None)  # (another graph's client)
    batches = _count_batches(monkeypatch, FsspecFS)
    warm = run_graph(g, cache="memory://warm-batch-gen", out=tmp_path / "out", registry=engine_registry, jobs=2)
    assert warm.computed == [] and len(warm.cached) == 12
    records = [b for b in batches if b[0] == "keys"]
    assert records == [["keys"] * 6, ["keys"] * 6], batches  # the sources together, then their dependants


def test_a_folder_reads_records_one_by_one(write, engine_registry, monkeypatch, tmp_path):
    g = write("wide.yaml", G)
    run_graph(g, cache=tmp_path / "c", registry=engine_registry, jobs=2)
    batches = _count_batches(monkeypatch, LocalFS)
    assert run_graph(g, cache=tmp_path / "c", registry=engine_registry, jobs=2).computed == []
    assert batches == []
