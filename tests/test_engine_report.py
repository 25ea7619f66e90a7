"""The HTML run report beside manifest.json (per node instance: time, cache hit, backend, image
thumbnails) and the animated preview of a sweep."""
import base64
import html.parser
import io
import json

import numpy as np
import pytest

from graphkit import run_graph

G = """\
graphkit: 1
name: rep
sweeps:
  g: {values: [0.05, 0.2, 0.6], name: "grey{index}"}
nodes:
  c: {type: Flat, foreach: g, params: {value: "${g.value}"}}
  n: {type: Const, params: {value: 2.0}}
  gif: {type: AnimatedPreview, inputs: {frames: "c[*].image"}, params: {path: anim/flat.gif, width: 32, fps: 5}}
outputs: {frames: c.image, gif: gif.file, n: n.out}
"""

FLAT = '''
import numpy as np
from graphkit import Node, Image, Field

class Flat(Node):
    """A 24x40 linear grey image."""
    outputs = {"image": Image}

    class Params(Node.Params):
        value: float = Field(0.5, ge=0)

    def compute(self):
        return Image(np.full((24, 40, 3), self.params.value, np.float32))
'''


@pytest.fixture
def reg(engine_registry, tmp_path, monkeypatch):
    (tmp_path / "flatnode.py").write_text(FLAT)
    monkeypatch.syspath_prepend(str(tmp_path))
    import flatnode

    engine_registry.add_provider("nodes", "tests", flatnode)
    return engine_registry


class Rows(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.rows, self.cur, self.cell, self.imgs, self.in_nodes = [], None, None, [], False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "table" and a.get("id") == "nodes":
            self.in_nodes = True
        if self.in_nodes and tag == "tr":
            self.cur = []
        if self.cur is not None and tag == "td":
            self.cell = ""
        if self.cur is not None and tag == "img":
            self.imgs.append((len(self.rows), a["src"]))

    def handle_data(self, data):
        if self.cell is not None:
            self.cell += data

    def handle_endtag(self, tag):
        if tag == "td" and self.cur is not None:
            self.cur.append(self.cell.strip())
            self.cell = None
        if tag == "tr" and self.cur is not None:
            if self.cur:
                self.rows.append(self.cur)
            self.cur = None
        if tag == "table":
            self.in_nodes = False


def srgb8(linear):
    import colour

    return np.round(colour.cctf_encoding(np.float64(linear), "sRGB") * 255)


def test_report_beside_the_manifest(tmp_path, write, reg):
    from PIL import Image as PILImage

    g = write("rep.yaml", G)
    out = tmp_path / "out"
    run_graph(g, cache=tmp_path / "c", out=out, registry=reg)
    manifest = json.loads((out / "manifest.json").read_text())
    p = Rows()
    p.feed((out / "report.html").read_text())
    by_node = {(r[0], r[1]): r for r in p.rows}
    assert set(by_node) == {("c", "grey0"), ("c", "grey1"), ("c", "grey2"), ("n", ""), ("gif", "")}
    assert len(by_node) == len(manifest["nodes"])
    for (base, inst), r in by_node.items():
        name = f"{base}[{inst}]" if inst else base
        assert r[3] == "computed" and r[6] == "numpy"
        assert r[4] == f"{manifest['nodes'][name]['seconds']:.3f} s"
        assert r[7] == manifest["nodes"][name]["key"][:12]
    # one thumbnail per image output (the three Flat instances, in sRGB for display) and of the GIF
    rows = [(p.rows[i][0], p.rows[i][1]) for i, _ in p.imgs]
    assert rows == [("c", "grey0"), ("c", "grey1"), ("c", "grey2"), ("gif", "")], rows
    for (row, src), v in zip(p.imgs, (0.05, 0.2, 0.6, 0.05)):  # the GIF's first frame
        im = np.asarray(PILImage.open(io.BytesIO(base64.b64decode(src.split(",", 1)[1]))).convert("RGB"))
        assert im.shape == ((24, 40, 3) if p.rows[row][0] == "c" else (19, 32, 3))  # at most 96 px a side
        assert np.abs(im.astype(float) - srgb8(v)).max() <= 2  # JPEG rounding

    # a fully cached re-run: every row cached, thumbnails from the cache
    r = run_graph(g, cache=tmp_path / "c", out=out, registry=reg)
    assert r.computed == []
    p2 = Rows()
    p2.feed((out / "report.html").read_text())
    assert all(row[3] == "cached" for row in p2.rows) and [s for _, s in p2.imgs] == [s for _, s in p.imgs]


def test_animated_preview_of_a_sweep(tmp_path, write, reg):
    from PIL import Image as PILImage

    g = write("rep.yaml", G)
    run_graph(g, cache=tmp_path / "c", out=tmp_path / "out", registry=reg)
    gif = PILImage.open(tmp_path / "out" / "anim" / "flat.gif")
    assert gif.n_frames == 3 and gif.info["duration"] == 200 and gif.info.get("loop") == 0
    for i, v in enumerate((0.05, 0.2, 0.6)):
        gif.seek(i)
        px = np.asarray(gif.convert("RGB"))
        assert px.shape == (19, 32, 3)  # 40x24 scaled to 32 wide
        assert np.abs(px.astype(float) - srgb8(v)).max() <= 1


def test_a_warm_report_reads_its_thumbnails_as_one_sheet(tmp_path, write, reg, monkeypatch):
    """The thumbnails a report shows are kept as one sheet (one record, one object): the next
    report of the same images reads the sheet, not a record and an object per image (what a warm
    run on an object store pays per request), and shows the same images."""
    import graphkit.report as report

    g = write("rep.yaml", G)
    run_graph(g, cache=tmp_path / "c", out=tmp_path / "cold", registry=reg)
    cold = Rows()
    cold.feed((tmp_path / "cold" / "report.html").read_text())
    assert len(cold.imgs) == 4  # the three frames and the gif

    def alone(*a, **k):
        pytest.fail("a thumbnail looked up or made alone")
    monkeypatch.setattr(report, "thumbnail", alone)
    run_graph(g, cache=tmp_path / "c", out=tmp_path / "warm", registry=reg)
    warm = Rows()
    warm.feed((tmp_path / "warm" / "report.html").read_text())
    assert warm.imgs == cold.imgs


TWO_PORTS = '''
import numpy as np
from graphkit import Node, Image

class ZetaAlpha(Node):
    """Two images, declared z before a (a record lists its outputs sorted: a before z)."""
    outputs = {"z": Image, "a": Image}

    def compute(self):
        return {"z": Image(np.full((8, 8, 3), 0.2, np.float32)), "a": Image(np.full((8, 8, 3), 0.7, np.float32))}
'''


def test_the_sheet_is_found_whatever_order_a_node_lists_its_ports(tmp_path, write, engine_registry, monkeypatch):
    import graphkit.report as report

    (tmp_path / "zetanode.py").write_text(TWO_PORTS)
    monkeypatch.syspath_prepend(str(tmp_path))
    import zetanode

    engine_registry.add_provider("nodes", "tests", zetanode)
    g = write("za.yaml", "graphkit: 1\nname: za\nnodes:\n  n: {type: ZetaAlpha}\noutputs: {z: n.z}\n")
    run_graph(g, cache=tmp_path / "c", out=tmp_path / "cold", registry=engine_registry)
    monkeypatch.setattr(report, "thumbnail", lambda *a, **k: pytest.fail("a thumbnail looked up or made alone"))
    run_graph(g, cache=tmp_path / "c", out=tmp_path / "warm", registry=engine_registry)
    imgs = [Rows() for _ in range(2)]
    for p, d in zip(imgs, ("cold", "warm")):
        p.feed((tmp_path / d / "report.html").read_text())
    assert len(imgs[0].imgs) == 2 and sorted(imgs[1].imgs) == sorted(imgs[0].imgs)  # (a row lists a record's ports sorted)
