"""Executors: run the part of a graph that the requested outputs need.

* :func:`run_local` — an embedded thread pool (default); no server.
* :func:`graphkit.dask_executor.run_dask` — the same node units on a Dask cluster.

Both return a :class:`RunResult`; :func:`export_outputs` then writes the requested outputs
into the ``--out`` folder (only after every node succeeded, each file written atomically) with
a run manifest.
"""
from __future__ import annotations

import json
import os
from collections import deque
import platform
import socket
import sys
import time
import uuid
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import GraphkitError, UsageError
from .paths import safe_relpath  # noqa: F401 - the one output-name rule (also graphkit.executor.safe_relpath)
from .report import report_file
from .runner import NodeOutcome, Session
from .types import File


@dataclass
class RunResult:
    graph_name: str
    outcomes: dict[str, NodeOutcome] = field(default_factory=dict)
    seconds: float = 0.0
    executor: str = "local"

    @property
    def computed(self) -> list[str]:
        return [n for n, o in self.outcomes.items() if not o.hit]

    @property
    def cached(self) -> list[str]:
        return [n for n, o in self.outcomes.items() if o.hit]


class Progress:
    """Receives run events; the CLI shows them (rich on a terminal, plain lines otherwise)."""

    def start(self, total: int) -> None: ...
    def running(self, node: str, node_type: str) -> None: ...
    def done(self, o: NodeOutcome) -> None: ...
    def report(self, node: str, fraction: float, message: str) -> None: ...
    def notice(self, message: str) -> None: ...
    def finish(self, ok: bool) -> None: ...


def input_digests(session: Session, name: str, outcomes: dict[str, NodeOutcome]) -> dict[str, str]:
    g = session.graph.nodes[name]
    return g.map_inputs(lambda src, sport: outcomes[src].outputs[sport])


def run_local(session: Session, targets: list[str], jobs: int = 1,
              progress: Progress | None = None) -> RunResult:
    """Run the nodes ``targets`` need, ``jobs`` at a time, in threads of this process."""
    progress = progress or Progress()
    graph = session.graph
    order = graph.upstream(targets)
    result = RunResult(graph.name)
    t0 = time.perf_counter()
    progress.start(len(order))
    with session.store.run_lock():
        if jobs <= 1:
            for n in order:
                progress.running(n, graph.nodes[n].type)
                o = session.run_node(n, input_digests(session, n, result.outcomes))
                result.outcomes[n] = o
                progress.done(o)
        else:
            _run_pool(session, order, jobs, progress, result)
    result.seconds = time.perf_counter() - t0
    return result


def _run_pool(session: Session, order: list[str], jobs: int, progress: Progress, result: RunResult) -> None:
    graph = session.graph
    wanted = set(order)
    waiting = {n: graph.nodes[n].sources() & wanted for n in order}
    dependants: dict[str, list[str]] = {n: [] for n in order}
    for n in order:
        for s in waiting[n]:
            dependants[s].append(n)
    ready = deque(n for n in order if not waiting[n])
    running: dict[Any, str] = {}
    error: BaseException | None = None
    with ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="graphkit") as pool:
        while ready or running:
            while ready and error is None and len(running) < jobs:
                n = ready.popleft()
                progress.running(n, graph.nodes[n].type)
                fut = pool.submit(session.run_node, n, input_digests(session, n, result.outcomes))
                running[fut] = n
            if not running:
                break
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in finished:
                n = running.pop(fut)
                exc = fut.exception()
                if exc is not None:
                    error = error or exc
                    continue
                o = fut.result()
                result.outcomes[n] = o
                progress.done(o)
                for d in dependants[n]:
                    waiting[d].discard(n)
                    if not waiting[d]:
                        ready.append(d)
            if error is not None:
                ready.clear()
    if error is not None:
        raise error


# ---------------------------------------------------------------------------------------------
# outputs


def export_value(ptype, value: Any, stem: str) -> tuple[str, bytes]:
    """How a non-File output is written: arrays as .npy, meshes as .ply, the rest as JSON."""
    import io

    import numpy as np

    if isinstance(value, File):
        return safe_relpath(value.name), value.data
    if ptype.export_ext == ".npy":
        meta, arrays = ptype.to_parts(value)
        buf = io.BytesIO()
        np.save(buf, arrays[-1] if ptype.name == "Spectrum" else arrays[0], allow_pickle=False)
        return f"{stem}.npy", buf.getvalue()
    if ptype.export_ext == ".ply":
        return f"{stem}.ply", value.export(file_type="ply")
    if ptype.name == "Scalar":  # a plain JSON number (its repr round-trips the float exactly)
        x = float(value)
        finite = abs(x) < float("inf")  # JSON has no inf/nan: those are written as "inf", "nan"
        return f"{stem}.json", json.dumps(x if finite else str(x)).encode()
    meta, _ = ptype.to_parts(value)
    return f"{stem}.json", json.dumps(meta, indent=1, sort_keys=True).encode()


def export_outputs(session: Session, result: RunResult, out_dir: str | os.PathLike,
                   manifest_extra: dict | None = None) -> list[Path]:
    """Write the graph's outputs and ``manifest.json`` into ``out_dir`` (atomically per file)."""
    graph = session.graph
    out = Path(out_dir)
    files: list[tuple[str, bytes]] = []
    for oname, (node, port) in graph.outputs.items():
        o = result.outcomes.get(node)
        if o is None:
            continue
        ptype = graph.nodes[node].cls.out_ports[port].type
        value = session.value(o.outputs[port], ptype)
        files.append(export_value(ptype, value, oname))
    seen: dict[str, str] = {}
    for name, _ in files:
        if name in seen:
            raise UsageError(f"two outputs would both be written to {out / name}")
        seen[name] = name
    manifest = build_manifest(session, result, manifest_extra)
    files.append(("manifest.json", json.dumps(manifest, indent=1, sort_keys=True).encode()))
    files.append(report_file(session, result, manifest))  # report.html, published with the manifest
    written = []
    staged = []
    try:
        out.mkdir(parents=True, exist_ok=True)
        for name, data in files:
            dest = out / name
            dest.parent.mkdir(parents=True, exist_ok=True)
            tmp = dest.parent / f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp"
            with open(tmp, "wb") as f:
                f.write(data)
            staged.append((tmp, dest))
        for tmp, dest in staged:
            os.replace(tmp, dest)
            written.append(dest)
    except OSError as e:
        for tmp, _ in staged:
            tmp.unlink(missing_ok=True)
        raise GraphkitError(f"cannot write outputs into {out}: {e.strerror or e}") from None
    return written


def package_versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("relightkit", "numpy", "pydantic", "OpenImageIO", "opencv-contrib-python-headless",
                 "trimesh", "colour-science", "pyopencl", "moderngl", "dask", "distributed"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    return out


def build_manifest(session: Session, result: RunResult, extra: dict | None = None) -> dict:
    g = session.graph
    nodes = {}
    for n, o in result.outcomes.items():
        gn = g.nodes[n]
        nodes[n] = {
            "type": o.type, "version": gn.cls.version, "key": o.key,
            "backend": o.backend, "backend_version": o.backend_version,
            "hit": o.hit, "seconds": round(o.seconds, 6), "outputs": o.outputs,
        }
    return {
        "graph": g.path, "name": g.name, "graph_digest": g.digest(), "params": g.params,
        "executor": result.executor, "seconds": round(result.seconds, 6),
        "host": socket.gethostname(), "platform": platform.platform(),
        "python": sys.version.split()[0], "packages": package_versions(),
        "cache": session.store.location, "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "nodes": nodes, **(extra or {}),
    }


def record_last_run(session: Session, result: RunResult) -> None:
    """Remember each node's key parts so `graphkit explain` can say what changed."""
    data = {}
    for n, o in result.outcomes.items():
        data[n] = {"key": o.key, "parts": session.readable_parts(session.graph.nodes[n], o.parts),
                   "outputs": o.outputs}
    session.store.save_run(graph_id(session.graph), data)


def graph_id(graph) -> str:
    import hashlib

    return f"{graph.name}-{hashlib.blake2b(graph.path.encode(), digest_size=6).hexdigest()}"


__all__ = ["run_local", "export_outputs", "RunResult", "Progress"]
