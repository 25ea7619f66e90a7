"""Paths from users: output names that must stay inside ``--out``, and input files.

One rule for every output name (``SaveImage`` / ``SaveMesh`` params and the names of ``File``
values the executor writes), so the nodes that check a name early (when the graph is loaded)
and the executor that checks it again before writing cannot drift apart: :func:`safe_relpath`
says whether one name stays inside ``--out``, :class:`OutputNames` whether a run's names fit
together there (validation, the plan and publishing all ask it).
"""
from __future__ import annotations

import os
import re
import stat
from pathlib import PurePosixPath

from .errors import UsageError

#: characters refused in output names: NUL (no OS accepts it), the Windows drive/stream
#: separator ':' (also refused on POSIX so a graph writes the same files everywhere)
_BAD_CHARS = {"\0": "a NUL byte", ":": "':'"}
#: a name safe_relpath gives back unchanged: '/'-separated parts, none empty, '.' or '..'
_NORMAL = re.compile(r"(?:(?!\.\.?(?:/|\Z))[^/\\:\0]+/)*(?!\.\.?\Z)[^/\\:\0]+\Z")


class UnsafePath(UsageError, ValueError):
    """An output name that would leave the output folder (or cannot be a file name): exit 2.
    Also a ValueError, so a pydantic validator turns it into a param error at load time."""


def safe_relpath(name: str, suffixes: tuple[str, ...] | None = None) -> str:
    """``name`` as a normalised POSIX relative path that stays inside the output folder.

    Backslashes count as separators (``a\\b.exr`` is ``a/b.exr``); ``.`` and empty parts are
    dropped (``./a//b.exr`` is ``a/b.exr``).  Refused with :class:`UnsafePath` (a
    ``ValueError`` too, so in a pydantic validator it is a param error at load time): empty
    names, absolute paths, ``..`` parts, names ending in '/', ':' (drive letters, NTFS streams)
    and NUL bytes.  With ``suffixes``, the extension (lower-cased) must be one of them.
    """
    norm = name if isinstance(name, str) and _NORMAL.match(name) else _normalised(name)
    if suffixes is not None:
        suffix = PurePosixPath(norm).suffix
        if suffix.lower() not in suffixes:
            raise UnsafePath(f"output name {name!r}: unknown extension {suffix!r}; use one of {', '.join(suffixes)}")
    return norm


def _normalised(name) -> str:
    """:func:`safe_relpath` of a name that is not one already (no Path object is built for those)."""
    if not isinstance(name, str) or not name:
        raise UnsafePath(f"output name {name!r}: must be a relative path inside the output folder, not empty")
    for ch, what in _BAD_CHARS.items():
        if ch in name:
            raise UnsafePath(f"output name {name!r}: must be a relative path inside the output folder "
                             f"({what} is not allowed)")
    text = name.replace("\\", "/")
    parts = [p for p in text.split("/") if p not in ("", ".")]
    if text.startswith("/") or text.endswith("/") or ".." in parts or not parts:
        raise UnsafePath(f"output name {name!r}: must be a relative path inside the output folder "
                         "to a file (no '..' part, no leading or trailing '/')")
    return str(PurePosixPath(*parts))


#: the files a run writes into --out beside its outputs
MANIFEST = "manifest.json"
REPORT = "report.html"
#: graphkit's own entries in --out (stages being written or published)
OWN_PREFIX = ".graphkit-"


class OutputNames:
    """The names one run writes into ``--out``, admitted one at a time by :meth:`claim`."""

    def __init__(self):
        self._files: dict[str, object] = {}  # name -> who writes it
        self._folders: dict[str, str] = {}  # folder -> a name below it

    def claim(self, name: str, who: object = None) -> tuple[str, object] | None:
        """None when ``name`` (a :func:`safe_relpath`) may be written by ``who``, beside the
        names claimed before; else (why not, in words; who already writes it, for a name
        claimed twice, else None).  The one rule: not the run's manifest or report, not
        graphkit's own ``.graphkit-*`` entries, not a name given twice, not a file where
        another name needs a folder."""
        if name in (MANIFEST, REPORT):
            return f"{name!r} is the name of the run's own {name} in --out", None
        if name.split("/")[0].startswith(OWN_PREFIX):
            return f"{name!r}: names starting with {OWN_PREFIX} are graphkit's own", None
        if name in self._files:
            return f"{name!r} is written by two outputs", self._files[name]
        if name in self._folders:
            return f"output {name!r} is a file but {self._folders[name]!r} needs it to be a folder", None
        folders = _folders_of(name)
        for d in folders:
            if d in self._files:
                return f"output {d!r} is a file but {name!r} needs it to be a folder", None
        self._files[name] = who
        for d in folders:
            self._folders.setdefault(d, name)
        return None

    def admit(self, name: str, out: object = "--out") -> None:
        """Claim ``name`` or refuse it (UsageError, exit 2) in the run's words."""
        clash = self.claim(name)
        if clash is not None:
            raise UsageError(f"refusing to write into {out}: {clash[0]}; rename that output (or its file)")


def _folders_of(name: str) -> list[str]:
    parts = name.split("/")
    return ["/".join(parts[:i]) for i in range(1, len(parts))]


def input_file_problem(path: str) -> str | None:
    """Why ``path`` cannot be read as an input file (None when it is a regular file, or does
    not exist: the caller reports a missing file its own way).  A FIFO, socket or device is
    refused before anyone opens it (opening a FIFO would wait for a writer forever)."""
    if "\0" in path:
        return f"{path!r} holds a NUL byte"
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    except OSError as e:
        return f"cannot read {path}: {e.strerror or e}"
    if stat.S_ISREG(st.st_mode):
        return None
    if stat.S_ISDIR(st.st_mode):
        return f"{path} is a folder, not a file"
    kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode)
            else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file")
    return f"{path} is {kind}, not a regular file"


__all__ = ["safe_relpath", "input_file_problem", "UnsafePath", "OutputNames", "MANIFEST", "REPORT"]
