"""The HTML run report (``report.html`` beside ``manifest.json``), like Nextflow's ``-with-report``.

One self-contained page: the run's summary, one row per swept node (instances computed and
cached, time), and one row per node instance with its time (and a bar to compare), cache hit,
backend and a thumbnail of each image output.  :func:`report_file` gives the file's name and
bytes for ``export_outputs`` to publish with the manifest.

Thumbnails are small JPEGs (at most :data:`THUMB_PX` pixels on a side) of ``Image`` and
``Mask`` outputs, shown in sRGB, and of exported PNG/JPEG/GIF/WebP files.  They are kept in the cache as ordinary entries keyed by the
image's digest, so a re-run's report does not decode its images again.
"""
from __future__ import annotations

import base64
import contextlib
import html
import io
import os
import time
from typing import Any

import numpy as np

from .hashing import key_digest
from .paths import REPORT

REPORT_NAME = REPORT  # the one list of the run's own files in --out: graphkit.paths
THUMB_PX = 96
THUMB_VERSION = 2  # 2: the box filter summed one axis at a time (rounds differently)
#: a report of a very large sweep keeps its first this-many thumbnails
MAX_THUMBS = 400
_IMAGE_TYPES = ("Image", "Mask")
_IMAGE_FILES = (".png", ".jpg", ".jpeg", ".gif", ".webp")


def _is_image_output(session, ptype, digest: str) -> bool:
    """Image and Mask values; File values already in memory (exported) that browsers can show."""
    if ptype.name in _IMAGE_TYPES:
        return True
    if ptype.name != "File":
        return False
    with session._memo_lock:
        v = session.memo.get(digest)
    return v is not None and str(getattr(v, "name", "")).lower().endswith(_IMAGE_FILES)


# ---------------------------------------------------------------------------------------------
# thumbnails


def _display_rgb(ptype_name: str, value: Any) -> np.ndarray:
    """8-bit sRGB H×W×3 of an Image (linear unless tagged otherwise) or a Mask."""
    if ptype_name == "Mask":
        px = np.asarray(value.alpha, np.float32)[:, :, None]
        linear = False
    else:
        px = np.asarray(value.pixels, np.float32)
        linear = not str(getattr(value, "colorspace", "lin")).lower().startswith("srgb")
    if px.shape[2] == 1:
        px = np.repeat(px, 3, axis=2)
    elif px.shape[2] == 2:
        px = np.concatenate([px, np.zeros_like(px[:, :, :1])], axis=2)
    px = px[:, :, :3]
    h, w = px.shape[:2]
    f = max(1, int(np.ceil(max(h, w) / THUMB_PX)))
    hh, ww = max(1, h // f), max(1, w // f)
    # box filter (summed one axis at a time: 5 × faster than one mean over both on a
    # 12-megapixel image, 0.05 s against 0.26 s, and a report holds tens of them)
    px = px[: hh * f, : ww * f].reshape(hh, f, ww, f, 3).sum(1).sum(2) / np.float32(f * f)
    px = np.nan_to_num(np.clip(px, 0.0, 1.0), nan=0.0)
    if linear:  # the sRGB transfer function (IEC 61966-2-1), for display only
        px = np.where(px <= 0.0031308, 12.92 * px, 1.055 * np.power(px, 1 / 2.4) - 0.055)
    return np.round(px * 255).astype(np.uint8)


def _file_rgb(value) -> np.ndarray:
    """8-bit RGB of an encoded PNG/JPEG/GIF/WebP file (its first frame), at most THUMB_PX a side."""
    from PIL import Image as PILImage

    im = PILImage.open(io.BytesIO(value.data))
    im.seek(0)
    im = im.convert("RGB")
    im.thumbnail((THUMB_PX, THUMB_PX), PILImage.Resampling.BOX)
    return np.asarray(im)


def _jpeg(rgb: np.ndarray) -> bytes:
    from PIL import Image as PILImage

    buf = io.BytesIO()
    PILImage.fromarray(rgb, "RGB").save(buf, "JPEG", quality=85, optimize=True)
    return buf.getvalue()


def thumbnail_key(digest: str) -> str:
    """The cache key of the thumbnail of the value ``digest``."""
    return key_digest({"thumbnail": THUMB_VERSION, "px": THUMB_PX, "value": digest})


def thumbnail(session, digest: str, ptype, rec: Any = ...) -> bytes | None:
    """JPEG bytes of a thumbnail of the image value ``digest``, from the cache when there
    (``rec``: its record, when already looked up); one made is kept in the cache."""
    from .types import File, port_type

    store = session.store
    key = thumbnail_key(digest)
    rec = store.get_record(key) if rec is ... else rec
    if rec is not None:
        try:
            return store.load_value(rec["outputs"]["jpeg"]["digest"], port_type(File)).data
        except Exception:  # noqa: BLE001 - a damaged thumbnail entry: make it again
            pass
    jpeg = _thumbnail_of(ptype, session.value(digest, ptype))
    keep_thumbnail(store, digest, jpeg)
    return jpeg


def _thumbnail_of(ptype, value) -> bytes:
    return _jpeg(_file_rgb(value) if ptype.name == "File" else _display_rgb(ptype.name, value))


def keep_thumbnail(store, digest: str, jpeg: bytes) -> None:
    """Keep the thumbnail of ``digest`` alone (an object and a record) for the next report; a
    read-only cache simply does not keep it."""
    from .types import File, port_type

    key = thumbnail_key(digest)
    try:
        d = store.put_value(port_type(File), File("thumbnail.jpg", jpeg))
        store.put_record(key, {"key": key, "node": "(report thumbnail)",
                               "parts": {"node_type": "report-thumbnail", "value": digest, "px": THUMB_PX},
                               "outputs": {"jpeg": {"digest": d, "type": "File"}}, "seconds": 0.0})
    except Exception:  # noqa: BLE001
        pass


def _sheet(store, key: str) -> dict[str, bytes] | None:
    """The thumbnails kept as one sheet under ``key`` (digest -> JPEG bytes), or None."""
    from .types import File, port_type

    rec = store.get_record(key)
    if rec is None:
        return None
    f = store.load_value(rec["outputs"]["sheet"]["digest"], port_type(File))
    return {d: f.data[at:at + n] for d, at, n in f.metadata["spans"]}


def _keep_sheet(store, key: str, jpegs: dict[str, bytes]) -> None:
    """Keep a report's thumbnails as one sheet (one object, one record): the next report of the
    same images reads two entries instead of two per image."""
    from .types import File, port_type

    spans, at = [], 0
    for d, jpeg in jpegs.items():
        spans.append([d, at, len(jpeg)])
        at += len(jpeg)
    sheet = File("thumbnails.bin", b"".join(jpegs.values()), {"spans": spans})
    d = store.put_value(port_type(File), sheet)
    store.put_record(key, {"key": key, "node": "(report thumbnails)",
                           "parts": {"node_type": "report-thumbnails", "px": THUMB_PX, "values": len(spans)},
                           "outputs": {"sheet": {"digest": d, "type": "File"}}, "seconds": 0.0})


# ---------------------------------------------------------------------------------------------
# the page

_CSS = """
body{font:14px/1.4 system-ui,sans-serif;margin:1.5em;color:#222}
h1{font-size:1.4em;margin:0 0 .2em} h2{font-size:1.1em;margin:1.4em 0 .4em}
table{border-collapse:collapse} td,th{padding:3px 8px;border-bottom:1px solid #e4e4e4;text-align:left;vertical-align:middle}
th{background:#f4f4f4;position:sticky;top:0} td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.hit{color:#2e7d32}.miss{color:#e65100;font-weight:600} .key{font-family:monospace;color:#777}
.bar{height:8px;background:#90caf9;display:inline-block;vertical-align:middle}
.meta td{border:0;padding:1px 10px 1px 0} img{display:inline-block;margin:1px 4px 1px 0;border:1px solid #ddd;max-height:64px}
input{margin:.3em 0 .6em;padding:3px 6px;width:18em}
"""

_JS = """
document.getElementById('q').addEventListener('input',function(e){var q=e.target.value.toLowerCase();
document.querySelectorAll('#nodes tbody tr').forEach(function(r){r.style.display=r.textContent.toLowerCase().indexOf(q)<0?'none':''})});
"""


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def report_html(session, result, manifest: dict) -> bytes:
    """The report page for a finished run (``manifest`` is the run's manifest.json content)."""
    graph = session.graph
    out = ["<!DOCTYPE html><html><head><meta charset='utf-8'>",
           f"<title>{_e(graph.name)}: graphkit run report</title><style>{_CSS}</style></head><body>",
           f"<h1>{_e(graph.name)}</h1><table class='meta'>"]
    out += [f"<tr><td>{_e(k)}</td><td>{_e(v)}</td></tr>" for k, v in _meta(graph, result, manifest)]
    out.append("</table>")
    out += _sweeps_table(graph, result.outcomes)
    out += _instances_table(session, graph, result.outcomes)
    out.append(f"<p class='key'>written by graphkit; manifest.json beside this file holds the same run "
               f"in full</p><script>{_JS}</script></body></html>\n")
    return "".join(out).encode("utf-8")


def _meta(graph, result, manifest: dict) -> list[tuple[str, Any]]:
    """The run's (label, value) lines at the top of the page."""
    outcomes = result.outcomes
    n_hit = sum(o.hit for o in outcomes.values())
    n_run = len(outcomes) - n_hit
    compute_s = sum(o.seconds for o in outcomes.values() if not o.hit)
    shown_path = graph.path
    with contextlib.suppress(ValueError):
        rel = os.path.relpath(graph.path)
        shown_path = graph.path if rel.startswith("..") else rel
    meta = [("graph", shown_path), ("finished", manifest.get("finished", time.strftime("%Y-%m-%dT%H:%M:%S%z"))),
            ("executor", result.executor), ("wall time", f"{result.seconds:.2f} s"),
            ("nodes", f"{len(outcomes)}: {n_run} computed ({compute_s:.2f} s of node time), {n_hit} cached"),
            ("host", manifest.get("host", "")), ("cache", manifest.get("cache", "")),
            ("graph digest", manifest.get("graph_digest", ""))]
    if graph.params:
        meta.append(("params", ", ".join(f"{k}={v!r}" for k, v in graph.params.items())))
    return meta


def _sweeps_table(graph, outcomes: dict) -> list[str]:
    """One row per swept node: its instances, how many computed and their node time."""
    bases: dict[str, list] = {}
    for n in [n for n in graph.nodes if n in outcomes]:
        g = graph.nodes[n]
        if g.sweep:
            bases.setdefault(g.base, []).append(outcomes[n])
    if not bases:
        return []
    out = ["<h2>Sweeps</h2><table><thead><tr><th>node</th><th>type</th><th>sweep</th><th>instances</th>"
           "<th>computed</th><th>cached</th><th>node time</th></tr></thead><tbody>"]
    for base, os_ in bases.items():
        g = graph.nodes[os_[0].name]
        hits = sum(o.hit for o in os_)
        secs = sum(o.seconds for o in os_ if not o.hit)
        out.append(f"<tr><td>{_e(base)}</td><td>{_e(g.type)}</td><td>{_e(g.sweep)}</td>"
                   f"<td class='num'>{len(os_)}</td><td class='num'>{len(os_) - hits}</td>"
                   f"<td class='num'>{hits}</td><td class='num'>{secs:.2f} s</td></tr>")
    out.append("</tbody></table>")
    return out


def _instances_table(session, graph, outcomes: dict) -> list[str]:
    """One row per node instance, in graph-file order (instances in sweep order)."""
    out = ["<h2>Node instances</h2><input id='q' placeholder='filter (node, type, backend…)'>"
           "<table id='nodes'><thead><tr><th>node</th><th>instance</th><th>type</th><th>cache</th>"
           "<th>time</th><th></th><th>backend</th><th>key</th><th>image outputs</th></tr></thead><tbody>"]
    longest = max((o.seconds for o in outcomes.values()), default=0.0) or 1.0
    thumbs = _Thumbnails(session)
    shown = [n for n in graph.nodes if n in outcomes]
    thumbs.look_up([(graph.nodes[n], outcomes[n]) for n in shown])
    for n in shown:
        o, g = outcomes[n], graph.nodes[n]
        bar = max(1, round(120 * o.seconds / longest))
        backend = o.backend + (f" {o.backend_version}" if o.backend != "numpy" else "")
        out.append(
            f"<tr><td>{_e(g.base or n)}</td><td>{_e(g.instance or '')}</td><td>{_e(o.type)}</td>"
            + (f"<td class='hit'>cached</td>" if o.hit else "<td class='miss'>computed</td>")
            + f"<td class='num'>{o.seconds:.3f} s</td><td><span class='bar' style='width:{bar}px'></span></td>"
            f"<td>{_e(backend)}</td><td class='key'>{_e(o.key[:12])}</td><td>{thumbs.of(g, o)}</td></tr>")
    out.append("</tbody></table>")
    thumbs.keep()
    if thumbs.skipped:
        out.append(f"<p>{thumbs.skipped} more image outputs have no thumbnail (at most {MAX_THUMBS} per report).</p>")
    return out


class _Thumbnails:
    """The image outputs' thumbnails as <img> tags, at most MAX_THUMBS per report.

    The thumbnails a report shows are kept as one sheet (one record, one object), keyed by the
    digests of every output that may be an image (Image, Mask, File): the next report of the
    same outputs reads two entries, not a record and an object per image, and shows the same
    images (a File value is known to be an image only once it is in memory; the sheet says so)."""

    def __init__(self, session):
        self.session, self.shown, self.skipped, self.failed = session, 0, 0, False
        self.records: dict[str, Any] = {}  # digest -> its thumbnail's record (looked up together)
        self.sheet: dict[str, bytes] | None = None  # the thumbnails read as one sheet
        self.made: dict[str, bytes] = {}  # the thumbnails this report shows
        self.unkept: dict[str, bytes] = {}  # those made from values in memory, not kept yet
        self.sheet_key = ""

    @staticmethod
    def candidates(g, o) -> list[tuple[str, str, Any]]:
        """(port, digest, port type) of the outputs of node ``g``'s outcome ``o`` that may be images."""
        out = []
        for port, d in o.outputs.items():
            p = g.cls.out_ports.get(port)
            if p is not None and p.type.name in (*_IMAGE_TYPES, "File"):
                out.append((port, d, p.type))
        return out

    def look_up(self, nodes) -> None:
        """The sheet of these (node, outcome) pairs' thumbnails; without one, the records and then
        the objects of the first MAX_THUMBS, read together (one batch each on an object store)."""
        store = self.session.store
        cands = [c for g, o in nodes for c in self.candidates(g, o)]
        values = sorted({d for _, d, _ in cands})  # (a computed node's ports and a record's come in other orders)
        self.sheet_key = key_digest({"thumbnails": THUMB_VERSION, "px": THUMB_PX, "values": values})
        try:
            self.sheet = _sheet(store, self.sheet_key) if cands else None
            if self.sheet is None:  # (a value in memory is thumbnailed from there: nothing to look up)
                digests = [d for _, d, t in cands if _is_image_output(self.session, t, d)
                           and not self._in_memory(d)][:MAX_THUMBS]
                recs = store.get_records(thumbnail_key(d) for d in digests)
                self.records = {d: recs[thumbnail_key(d)] for d in digests}
                store.prefetch_values(r["outputs"]["jpeg"]["digest"] for r in self.records.values() if r)
        except Exception:  # noqa: BLE001 - a report never fails a run (each is looked up alone)
            self.sheet, self.records = None, {}

    def keep(self) -> None:
        """Every thumbnail shown, kept as one sheet (unless read from one); where some are
        missing, those made from values in memory are kept alone instead."""
        if self.sheet is not None or not self.made:
            return
        if self.skipped or self.failed:
            for d, jpeg in self.unkept.items():
                keep_thumbnail(self.session.store, d, jpeg)
            return
        with contextlib.suppress(Exception):  # (a read-only cache simply does not keep it)
            _keep_sheet(self.session.store, self.sheet_key, self.made)

    def _in_memory(self, d: str) -> bool:
        with self.session._memo_lock:
            return d in self.session.memo

    def of(self, g, o) -> str:
        imgs = []
        for port, d, ptype in self.candidates(g, o):
            jpeg = (self.sheet or {}).get(d)
            if jpeg is None and not _is_image_output(self.session, ptype, d):
                continue
            if self.shown >= MAX_THUMBS:
                self.skipped += 1
                continue
            if jpeg is None:
                jpeg = self._made_alone(d, ptype)
            if jpeg:
                self.shown += 1
                self.made[d] = jpeg
                imgs.append(f"<img alt='{_e(port)}' title='{_e(port)}' src='data:image/jpeg;base64,"
                            f"{base64.b64encode(jpeg).decode()}'>")
            else:
                self.failed = True
        return "".join(imgs)

    def _made_alone(self, d: str, ptype) -> bytes | None:
        """A thumbnail not on a sheet: made from the value in memory (kept by :meth:`keep`, on
        the sheet as a rule: no entry of its own), else from the cache or the stored value."""
        try:
            if self._in_memory(d):
                self.unkept[d] = _thumbnail_of(ptype, self.session.value(d, ptype))
                return self.unkept[d]
            return thumbnail(self.session, d, ptype, self.records.get(d, ...))
        except Exception:  # noqa: BLE001 - a report never fails a run
            return None


def report_file(session, result, manifest: dict) -> tuple[str, bytes]:
    """(file name, bytes) of the report, for :func:`graphkit.publish.export_outputs`."""
    return REPORT_NAME, report_html(session, result, manifest)


__all__ = ["report_file", "report_html", "thumbnail", "REPORT_NAME"]
