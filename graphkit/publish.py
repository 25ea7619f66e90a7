"""Publishing a run's outputs into the ``--out`` folder, as one unit with the run manifest.

The files are written and fsynced in a stage folder inside ``--out``, which is renamed to mark
it complete (the commit point) and then published by renames, the manifest last; a run killed
while publishing is finished by the next one (:func:`recover`).  See :func:`export_outputs`.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import platform
import re
import shutil
import socket
import stat
import sys
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

import xxhash

from .errors import GraphkitError, UsageError
from .paths import MANIFEST, OWN_PREFIX, OutputNames, safe_relpath
from .report import report_file
from .types import File

if TYPE_CHECKING:
    from .executor import RunResult
    from .runner import Session


def export_value(ptype, value: Any, stem: str) -> tuple[str, bytes]:
    """How a non-File output is written: arrays as .npy, meshes as .ply, the rest as JSON."""
    if isinstance(value, File):
        return safe_relpath(value.name), value.data
    if ptype.export_ext == ".npy":
        meta, arrays = ptype.to_parts(value)
        return f"{stem}.npy", npy_bytes(arrays[-1] if ptype.name == "Spectrum" else arrays[0])
    if ptype.export_ext == ".ply":
        return f"{stem}.ply", value.export(file_type="ply")
    if ptype.name == "Scalar":  # a plain JSON number (its repr round-trips the float exactly)
        x = float(value)
        finite = abs(x) < float("inf")  # JSON has no inf/nan: those are written as "inf", "nan"
        return f"{stem}.json", json.dumps(x if finite else str(x)).encode()
    meta, _ = ptype.to_parts(value)
    return f"{stem}.json", json.dumps(meta, indent=1, sort_keys=True).encode()


_NPY_HEADS: dict[tuple, bytes] = {}  # (dtype, shape) -> np.save's header of a C-ordered array


def npy_bytes(a) -> bytes:
    """What ``np.save(f, a, allow_pickle=False)`` writes.  Its header depends only on the dtype
    and shape of a C-ordered plain array: made by np.save once per (dtype, shape), then reused."""
    import io

    import numpy as np

    plain = a.dtype.fields is None and not a.dtype.hasobject and a.dtype.metadata is None
    if not (plain and a.flags.c_contiguous):
        buf = io.BytesIO()
        np.save(buf, a, allow_pickle=False)
        return buf.getvalue()
    head = _NPY_HEADS.get((a.dtype.str, a.shape))
    if head is None:
        buf = io.BytesIO()
        np.save(buf, a, allow_pickle=False)
        head = _NPY_HEADS[(a.dtype.str, a.shape)] = buf.getvalue()[: buf.tell() - a.nbytes]
    return head + a.tobytes()


STAGE_PREFIX = OWN_PREFIX + "stage-"      # a run's outputs being written (removed by the next run)
PUBLISH_PREFIX = OWN_PREFIX + "publish-"  # a complete stage being published (finished by the next run)
_LEGACY_TMP = re.compile(r"^\..+\.[0-9a-f]{8}\.tmp$")  # per-file temps of graphkit < issue 10


def check_output_names(names: list[str], out: Path | str = "--out") -> None:
    """Refuse output names that do not fit together in --out (:class:`graphkit.paths.OutputNames`)."""
    taken = OutputNames()
    for name in names:
        taken.admit(name, out)


def export_outputs(session: Session, result: RunResult, out_dir: str | os.PathLike,
                   manifest_extra: dict | None = None) -> list[Path]:
    """Publish the graph's outputs and ``manifest.json`` into ``out_dir`` as one unit.

    The files are written and fsynced in a fresh stage folder inside ``out_dir``, which is then
    renamed to mark it complete (the commit point) and published by renames plus directory
    fsyncs: the old manifest is set aside first and the new one installed last.  So at every
    instant ``manifest.json`` either describes the previous run's files or this run's, and a
    run killed while publishing is finished by the next one (:func:`publish`).  A file that
    already holds its bytes there (a warm run's) is left in place (:func:`_in_place`).  Folders
    that are symlinks inside ``out_dir`` are refused, never followed."""
    graph = session.graph
    out = Path(out_dir)
    files: list[tuple[str, bytes]] = []
    session.prefetch_values(result.outcomes[n].outputs[p] for n, p in graph.outputs.values() if n in result.outcomes)
    for oname, (node, port) in graph.outputs.items():
        o = result.outcomes.get(node)
        if o is None:
            continue
        ptype = graph.nodes[node].cls.out_ports[port].type
        value = session.value(o.outputs[port], ptype, (node, port))
        files.append(export_value(ptype, value, oname))
    check_output_names([n for n, _ in files], out)
    manifest = build_manifest(session, result, manifest_extra)
    files.append(report_file(session, result, manifest))  # report.html, published with the manifest
    manifest["files"] = {n: file_entry(d) for n, d in files}
    try:
        publish(out, files, json.dumps(manifest, indent=1, sort_keys=True).encode())
    except OSError as e:
        raise GraphkitError(f"cannot write outputs into {out}: {e.strerror or e}") from None
    return [out / n for n, _ in files] + [out / MANIFEST]


_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


def _open_dir(parent_fd: int, name: str, create: bool, what: str) -> int | None:
    """Open folder ``name`` below ``parent_fd`` without following a symlink."""
    try:
        return os.open(name, _DIR_FLAGS, dir_fd=parent_fd)
    except FileNotFoundError:
        if not create:
            return None
        with contextlib.suppress(FileExistsError):
            os.mkdir(name, dir_fd=parent_fd)
        os.fsync(parent_fd)
        return os.open(name, _DIR_FLAGS, dir_fd=parent_fd)
    except OSError as e:
        if e.errno in (errno.ELOOP, errno.ENOTDIR):
            raise UsageError(f"refusing to write {what}: {name!r} in the --out folder is a symlink or not a "
                             "folder (graphkit never follows links inside --out)") from None
        raise


@contextlib.contextmanager
def _parent(base_fd: int, relname: str, create: bool):
    """(fd of the folder holding ``relname`` below ``base_fd``, base name); fd None if absent."""
    if "/" not in relname:  # (the usual case: base_fd itself, not a copy of it)
        yield base_fd, relname
        return
    comps = relname.split("/")
    fd = os.dup(base_fd)
    try:
        for c in comps[:-1]:
            nfd = _open_dir(fd, c, create, relname)
            os.close(fd)
            fd = nfd
            if fd is None:
                break
        yield fd, comps[-1]
    finally:
        if fd is not None:
            os.close(fd)


def _exists(dir_fd: int, name: str) -> bool:
    try:
        os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
        return True
    except FileNotFoundError:
        return False


def _read(dir_fd: int, name: str) -> bytes | None:
    try:
        fd = os.open(name, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0), dir_fd=dir_fd)
    except FileNotFoundError:
        return None
    with open(fd, "rb") as f:
        return f.read()


def _write(dir_fd: int, name: str, data: bytes) -> None:
    fd = os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
                 | getattr(os, "O_CLOEXEC", 0), 0o666, dir_fd=dir_fd)
    with open(fd, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def publish(out: Path, files: list[tuple[str, bytes]], manifest: bytes) -> None:
    """Stage ``files`` + ``manifest`` inside ``out`` and publish them (see export_outputs).
    Files whose bytes are already published there (:func:`_in_place`) are left as they are."""
    import fcntl

    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    if created:
        _fsync_path(out.parent)
    dfd = os.open(out, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        fcntl.flock(dfd, fcntl.LOCK_EX)  # one publisher per --out; the OS drops it if we die
        recover(dfd)
        entries = json.loads(manifest).get("files") or {}  # (hashed once, by the caller that built it)
        kept = _in_place(dfd, files, entries)  # (regular files: no folder in their way)
        written = [(n, d) for n, d in files if n not in kept]
        _refuse_folders_in_the_way(dfd, out, [n for n, _ in written])
        token = uuid.uuid4().hex[:12]
        _stage(dfd, out, token, written + [(MANIFEST, manifest)])
        _roll_forward(dfd, out, PUBLISH_PREFIX + token)
        _clean_legacy_temps(dfd, [n for n, _ in files])
    finally:
        os.close(dfd)


def _refuse_folders_in_the_way(dfd: int, out: Path, names: list[str]) -> None:
    """Before committing: refuse symlinked folders on the way to ``names`` and folders in their place."""
    for name in names:
        with _parent(dfd, name, create=False) as (pfd, base):
            if pfd is not None and _exists(pfd, base):
                st = os.stat(base, dir_fd=pfd, follow_symlinks=False)
                if stat.S_ISDIR(st.st_mode):
                    raise UsageError(f"cannot write output {name!r}: {out / name} is a folder")


def _stage(dfd: int, out: Path, token: str, files: list[tuple[str, bytes]]) -> None:
    """Write and fsync ``files`` in a stage folder, then rename it complete (the commit point)."""
    stage = STAGE_PREFIX + token
    os.mkdir(stage, dir_fd=dfd)
    try:
        sfd = os.open(stage, _DIR_FLAGS, dir_fd=dfd)
        try:
            for name, data in files:
                with _parent(sfd, name, create=True) as (pfd, base):
                    _write(pfd, base, data)  # written and fsynced
            _fsync_dirs(sfd, [n for n, _ in files])  # each folder once, after its files
        finally:
            os.close(sfd)
        os.rename(stage, PUBLISH_PREFIX + token, src_dir_fd=dfd, dst_dir_fd=dfd)  # the commit point
        os.fsync(dfd)
    except BaseException:
        shutil.rmtree(out / stage, ignore_errors=True)
        raise


def file_entry(data: bytes) -> dict:
    """What the manifest records of a published file."""
    return {"bytes": len(data), "xxh3": xxhash.xxh3_128_hexdigest(data)}


def _in_place(dfd: int, files: list[tuple[str, bytes]], entries: dict) -> set[str]:
    """The names of ``files`` already published in --out with exactly these bytes: the
    manifest there records the same size and xxh3-128 as the new one (``entries``), and the
    file itself still holds them.

    The file is re-read and compared byte for byte, not trusted by a stat signature: size and
    mtime are put back by ordinary tools after an edit (``cp -p``, ``rsync -t``, ``touch -r``),
    and the inode and ctime change with the very renames that publish the file, after the
    manifest is written.  Reading costs a fraction of writing, fsyncing and renaming the file
    again.  Only a regular file with one link counts (another name for it could change it),
    opened without following a symlink and without blocking (a FIFO in its place)."""
    try:
        old = json.loads(_read(dfd, MANIFEST) or b"{}").get("files")
    except (ValueError, AttributeError):
        return set()
    if not isinstance(old, dict):
        return set()
    return {name for name, data in files
            if entries.get(name) is not None and old.get(name) == entries[name] and _holds(dfd, name, data)}


def _holds(dfd: int, name: str, data: bytes) -> bool:
    """Whether ``name`` below ``dfd`` is a regular, singly linked file holding exactly ``data``."""
    with _parent(dfd, name, create=False) as (pfd, base):
        if pfd is None:
            return False
        try:
            fd = os.open(base, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0)
                         | getattr(os, "O_CLOEXEC", 0), dir_fd=pfd)
        except OSError:
            return False
        with open(fd, "rb") as f:
            st = os.fstat(fd)
            return (stat.S_ISREG(st.st_mode) and st.st_nlink == 1 and st.st_size == len(data)
                    and f.read(len(data) + 1) == data)


def recover(dfd: int) -> None:
    """Finish what a killed run left in --out: complete stages are published, partial ones removed."""
    for name in sorted(os.listdir(dfd)):
        if name.startswith(PUBLISH_PREFIX):
            _roll_forward(dfd, None, name)
        elif name.startswith(STAGE_PREFIX):
            _rmtree_at(dfd, name)
    _clean_legacy_temps(dfd, [])


def _roll_forward(dfd: int, out: Path | None, pname: str) -> None:
    """Publish the complete stage ``pname``; idempotent, so a killed publish can be finished."""
    pfd = os.open(pname, _DIR_FLAGS, dir_fd=dfd)
    try:
        raw = _read(pfd, MANIFEST)
        if raw is not None:
            new = json.loads(raw)
            if _exists(dfd, MANIFEST) and not _exists(pfd, "old-manifest.json"):
                # from here until the new manifest is in place, --out has no manifest.json: no
                # instant where a manifest sits beside files it does not describe
                os.rename(MANIFEST, "old-manifest.json", src_dir_fd=dfd, dst_dir_fd=pfd)
                os.fsync(pfd)
                os.fsync(dfd)
            staged = _files_below(pfd)  # what is not published yet (a file kept in place never was staged)
            for name in new.get("files", {}):
                if name not in staged:
                    continue
                with _parent(pfd, name, create=False) as (sp, base), _parent(dfd, name, create=True) as (dp, _):
                    os.rename(base, base, src_dir_fd=sp, dst_dir_fd=dp)
            _fsync_dirs(dfd, list(new.get("files", {})))  # the renames are durable ...
            os.rename(MANIFEST, MANIFEST, src_dir_fd=pfd, dst_dir_fd=dfd)  # ... before the manifest
            os.fsync(dfd)
        else:
            new = json.loads(_read(dfd, MANIFEST) or b"{}")
        _remove_stale(dfd, pfd, new)
    finally:
        os.close(pfd)
    _rmtree_at(dfd, pname)


def _files_below(fd: int, prefix: str = "") -> set[str]:
    """The relative names of the files below the folder open as ``fd`` (symlinks not followed)."""
    names = set()
    for entry in os.listdir(fd):
        if stat.S_ISDIR(os.stat(entry, dir_fd=fd, follow_symlinks=False).st_mode):
            sub = os.open(entry, _DIR_FLAGS, dir_fd=fd)
            try:
                names |= _files_below(sub, f"{prefix}{entry}/")
            finally:
                os.close(sub)
        else:
            names.add(prefix + entry)
    return names


def _remove_stale(dfd: int, pfd: int, new: dict) -> None:
    """Remove the previous run's files (listed in the stage's old-manifest.json) that the new
    manifest does not list."""
    old_raw = _read(pfd, "old-manifest.json")
    old = {}
    with contextlib.suppress(ValueError):
        old = json.loads(old_raw) if old_raw else {}
    stale = set(old.get("files", {}) if isinstance(old, dict) else ()) - set(new.get("files", {}))
    for name in sorted(stale):  # the previous run's files that this run does not write
        with contextlib.suppress(ValueError, UsageError):
            name = safe_relpath(name)
            with _parent(dfd, name, create=False) as (dp, base):
                if dp is not None and _exists(dp, base) and not stat.S_ISDIR(
                        os.stat(base, dir_fd=dp, follow_symlinks=False).st_mode):
                    os.unlink(base, dir_fd=dp)
                    os.fsync(dp)


def _rmtree_at(dfd: int, name: str) -> None:
    fd = os.open(name, _DIR_FLAGS, dir_fd=dfd)
    try:
        for entry in os.listdir(fd):
            st = os.stat(entry, dir_fd=fd, follow_symlinks=False)
            if stat.S_ISDIR(st.st_mode):
                _rmtree_at(fd, entry)
            else:
                os.unlink(entry, dir_fd=fd)
    finally:
        os.close(fd)
    os.rmdir(name, dir_fd=dfd)
    os.fsync(dfd)


def _clean_legacy_temps(dfd: int, names: list[str]) -> None:
    dirs = {""} | {n.rsplit("/", 1)[0] for n in names if "/" in n}
    for d in sorted(dirs):
        with _parent(dfd, f"{d}/x" if d else "x", create=False) as (fd, _):
            if fd is None:
                continue
            for entry in os.listdir(fd):
                if _LEGACY_TMP.match(entry):
                    with contextlib.suppress(OSError):
                        os.unlink(entry, dir_fd=fd)


def _fsync_dirs(base_fd: int, names: list[str]) -> None:
    """fsync every folder that holds one of ``names`` below ``base_fd`` (each once)."""
    for d in sorted({n.rsplit("/", 1)[0] for n in names if "/" in n}):
        with _parent(base_fd, f"{d}/x", create=False) as (fd, _):
            if fd is not None:
                os.fsync(fd)
    os.fsync(base_fd)


def _fsync_path(p: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(p, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


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


__all__ = ["export_outputs", "publish", "recover", "check_output_names", "MANIFEST"]
