"""One GLSL source for desktop OpenGL and WebGL2: a small preprocessor over ``shaders/glsl/``.

The shaders in ``shaders/glsl/`` are written once, in the part of GLSL 3.30 core that GLSL ES
3.00 also has (no ``double``, ``noperspective``, ``layout(binding=…)``, ``#extension``,
``texture2D``/``gl_FragColor``…).  A shader file starts with ``#version 330``; :func:`source`
turns it into

* ``"330"``: GLSL 3.30 core, for moderngl (``#version 330 core``);
* ``"es300"``: GLSL ES 3.00, for WebGL2 (``#version 300 es`` and ``highp`` default precisions
  for floats, ints and the sampler types, which ES requires and desktop GL ignores),

and, for both, adds the given ``defines`` (``#define NAME VALUE`` after the version line: a
shader specialised at compile time, e.g. its number of lights or whether it casts shadows, so
that neither llvmpipe nor SwiftShader runs the code of a branch that is switched off) and
replaces ``#include "file"`` lines by that file of ``shaders/glsl/`` (each file at most once,
with ``#line`` directives so compile errors name the right line: source-string 0 is the
shader itself, 1, 2, … its includes in order).  The files are found with
:func:`graphkit.resources.shader_source` (an installed wheel or a checkout).

A line that uses a construct outside the shared subset is refused with ``file:line`` (a
:class:`GlslError`), so a change that would build for one target only fails in both.
"""
from __future__ import annotations

import re
import threading

TARGETS = {"330": "#version 330 core", "es300": "#version 300 es"}
#: what GLSL ES 3.00 needs and GLSL 3.30 does not have: default precisions (ES gives floats
#: none in fragment shaders and the sampler types lowp or none)
ES_PRECISION = ("precision highp float;", "precision highp int;", "precision highp sampler2D;",
                "precision highp sampler2DArray;", "precision highp sampler3D;",
                "precision highp sampler2DShadow;")

_INCLUDE = re.compile(r'^\s*#\s*include\s+"([A-Za-z0-9_./-]+)"\s*$')
_VERSION = re.compile(r"^\s*#\s*version\s+(\d+)\s*(\w*)\s*$")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# constructs of GLSL 3.30 core that GLSL ES 3.00 lacks (or the reverse), with what to use instead
_NOT_SHARED = [
    (re.compile(r"\b(double|dvec[234]|dmat[234](x[234])?)\b"), "double precision (ES has none)"),
    (re.compile(r"\bnoperspective\b"), "noperspective (not in GLSL ES 3.00)"),
    (re.compile(r"\blayout\s*\([^)]*\bbinding\b"), "layout(binding=…) (not in GLSL 3.30 / ES 3.00): set sampler units as uniforms"),
    (re.compile(r"^\s*#\s*extension\b"), "#extension (targets differ)"),
    (re.compile(r"\b(texture[123]D|texture2DRect|shadow2D|gl_FragColor|gl_FragData|attribute|varying)\b"),
     "pre-1.30 syntax (use texture(), in/out and declared outputs)"),
    (re.compile(r"\bsampler(1D|1DArray|2DRect|Buffer|2DMS)\w*\b"), "a sampler type GLSL ES 3.00 lacks"),
    (re.compile(r"^\s*precision\b"), "precision statements (the preprocessor adds them for ES)"),
]


class GlslError(ValueError):
    """A shader that cannot be preprocessed (missing include, an include cycle, a construct
    outside the shared subset); the message names the file and line."""


_lock = threading.Lock()
_memo: dict[tuple, str] = {}


def source(name: str, target: str = "330", defines: dict | None = None) -> str:
    """The shader ``shaders/glsl/<name>`` for ``target`` ("330" or "es300") with ``defines``
    (names → int, float or bool values) prepended; see the module docstring."""
    if target not in TARGETS:
        raise GlslError(f"unknown GLSL target {target!r} (one of: {', '.join(TARGETS)})")
    defs = _check_defines(defines or {})
    key = (name, target, tuple(sorted(defs.items())))
    with _lock:
        hit = _memo.get(key)
    if hit is not None:
        return hit
    body, files = _expand(name)
    head = [TARGETS[target]]
    if target == "es300":
        head += ES_PRECISION
    head += [f"#define GK_TARGET_{'ES' if target == 'es300' else 'GL'} 1"]
    head += [f"#define {k} {v}" for k, v in defs.items()]
    head.append("#line 2 0")  # the shader's own line 1 was its #version
    out = "\n".join(head + body) + "\n"
    with _lock:
        _memo[key] = out
    return out


def files(name: str) -> list[str]:
    """``name`` and the files it includes (directly or not), in include order."""
    return _expand(name)[1]


def _check_defines(defines: dict) -> dict[str, str]:
    out = {}
    for k, v in defines.items():
        if not isinstance(k, str) or not _NAME.fullmatch(k) or k.startswith("GL_") or k.startswith("GK_TARGET"):
            raise GlslError(f"bad GLSL define name {k!r}")
        if isinstance(v, bool):
            out[k] = "1" if v else "0"
        elif isinstance(v, int):
            out[k] = str(v)
        elif isinstance(v, float):
            out[k] = repr(v) if "." in repr(v) or "e" in repr(v) else f"{v}.0"
        else:
            raise GlslError(f"GLSL define {k}: {v!r} is not an int, float or bool")
    return out


def _read(rel: str) -> str:
    from .resources import shader_source

    try:
        return shader_source(f"glsl/{rel}")
    except FileNotFoundError as e:
        raise GlslError(str(e)) from None


def _expand(name: str) -> tuple[list[str], list[str]]:
    """(lines of ``name`` with its includes expanded, without the #version line; files)."""
    order: list[str] = []

    def walk(rel: str, stack: tuple[str, ...]) -> list[str]:
        if rel in stack:
            raise GlslError(f"glsl/{rel}: include cycle {' -> '.join(stack + (rel,))}")
        if rel in order:
            return []  # each file once
        order.append(rel)
        num = len(order) - 1
        lines = _read(rel).splitlines()
        out: list[str] = []
        start = 0
        if not stack:
            m = _VERSION.match(lines[0]) if lines else None
            if not m or m.group(1) != "330" or m.group(2) not in ("", "core"):
                raise GlslError(f"glsl/{rel}:1: a shader starts with '#version 330' (the shared "
                                "GLSL 3.30 / ES 3.00 dialect); the preprocessor writes each target's own")
            start = 1
        in_block = False
        for i, line in enumerate(lines[start:], start + 1):
            code, in_block = _strip_comments(line, in_block)
            if _VERSION.match(code):
                raise GlslError(f"glsl/{rel}:{i}: #version belongs on the first line of a shader only")
            for pat, what in _NOT_SHARED:
                if pat.search(code):
                    raise GlslError(f"glsl/{rel}:{i}: {what}")
            m = _INCLUDE.match(code)
            if m:
                inc = m.group(1)
                sub = walk(inc, stack + (rel,))
                if sub:
                    out.append(f"#line 1 {order.index(inc)}")
                    out.extend(sub)
                    out.append(f"#line {i + 1} {num}")
                continue
            out.append(line)
        return out

    body = walk(name, ())
    return body, list(order)


def _strip_comments(line: str, in_block: bool) -> tuple[str, bool]:
    """The code of one line without comments; whether a /* … */ block is still open."""
    out, i = [], 0
    while i < len(line):
        if in_block:
            j = line.find("*/", i)
            if j < 0:
                return "".join(out), True
            i, in_block = j + 2, False
            continue
        if line.startswith("//", i):
            break
        if line.startswith("/*", i):
            in_block, i = True, i + 2
            continue
        out.append(line[i])
        i += 1
    return "".join(out), in_block
