"""``builtin:NAME`` input files: data shipped inside an installed package.

One resolver for every node that reads a file (LoadImage, LoadMesh, LoadCameraJson here;
LoadScene in nodes/loscos with its own table).  Files are found through
``importlib.resources`` relative to the package that ships them, so they are found the same
way in a checkout, an editable install, a wheel installed into any prefix or with
``pip install --target``.

``builtin:NAME`` names one file; when NAME is a folder, ``builtin:NAME/sub/file`` names a file
inside it (``builtin:sample_capture/photo.exr``).
"""
from __future__ import annotations

from graphkit import BadInput

PREFIX = "builtin:"

#: the builtins of the nodes in nodes/io: name -> (package, path inside it, description)
BUILTIN = {
    "astronaut": ("skimage", "data/astronaut.png", "scikit-image's astronaut photo (NASA, public domain)"),
    "sample_capture": ("nodes.paris", "data/sample_capture",
                       "a Mitsuba capture of a head: photo.exr, probe.exr, mesh.ply, camera.json "
                       "(nodes/paris/data/make_capture.py)"),
    "envmaps": ("nodes.paris", "data/envmaps",
                "small equirectangular HDR environment maps: studio.exr, interior.exr, city.exr, "
                "courtyard.exr, forest.exr (Blender's CC0 studio lights), sky.exr (Mitsuba sunsky), "
                "window.exr (a room with one window) (nodes/paris/data/make_envmaps.py)"),
}


def is_builtin(value) -> bool:
    return isinstance(value, str) and value.startswith(PREFIX)


def builtin_path(value: str, param: str = "path", table: dict | None = None, *, package: str | None = None,
                 folder: str = "", what: str = "file") -> str:
    """The file system path of ``builtin:NAME[/sub/path]``; BadInput naming ``param`` when
    the name is unknown, the sub-path leaves its folder, or the package is not installed.

    ``table`` maps NAME to ``(package, path, description)`` (default: :data:`BUILTIN`), or to
    a bare path inside ``package``/``folder`` (as nodes/loscos's scene table does)."""
    from importlib.resources import files
    from pathlib import Path, PurePosixPath

    table = BUILTIN if table is None else table
    name, _, sub = value[len(PREFIX):].partition("/")
    if name not in table:
        raise BadInput(param, f"unknown builtin {what} '{value}' (known: "
                       + ", ".join(PREFIX + k for k in table) + ")")
    entry = table[name]
    pkg, rel = (entry[0], entry[1]) if isinstance(entry, tuple) else (package, f"{folder}/{entry}" if folder else entry)
    parts = [p for p in PurePosixPath(sub).parts if p not in ("", ".")] if sub else []
    if ".." in parts or sub.startswith("/"):
        raise BadInput(param, f"'{value}': a builtin sub-path cannot leave {PREFIX}{name}")
    try:
        res = files(pkg).joinpath(rel, *parts)
    except ModuleNotFoundError:
        raise BadInput(param, f"{PREFIX}{name} needs the package '{pkg}', which is not installed") from None
    if not isinstance(res, Path):  # e.g. a zipped install: there is no file to hand to a reader
        raise BadInput(param, f"{PREFIX}{name}: package '{pkg}' is not installed as plain files")
    if not res.exists():
        raise BadInput(param, f"'{value}' is not in {PREFIX}{name} ({res} is missing: a broken install?)")
    if res.is_dir():
        inside = sorted(p.name for p in res.iterdir() if p.is_file() and not p.name.startswith("."))
        raise BadInput(param, f"'{value}' is a folder: name a file in it, e.g. {value.rstrip('/')}/"
                       + (inside[0] if inside else "FILE") + (f" (it holds {', '.join(inside)})" if inside else ""))
    return str(res)


class BuiltinFiles:
    """Mixin for node types whose ``InputFile`` params also take ``builtin:NAME`` (put it
    before ``Node`` in the bases)."""

    builtin_table: dict | None = None  # None: nodes/io's BUILTIN
    builtin_what: str = "file"  # in messages: "unknown builtin image 'builtin:moon'"

    @classmethod
    def resolve_file(cls, param, value, base_dir):
        if is_builtin(value):
            return builtin_path(value, param, cls.builtin_table, what=cls.builtin_what)
        return super().resolve_file(param, value, base_dir)


__all__ = ["BUILTIN", "BuiltinFiles", "builtin_path", "is_builtin"]
