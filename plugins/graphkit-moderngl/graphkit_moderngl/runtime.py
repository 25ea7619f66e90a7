"""The per-process OpenGL state: one EGL standalone context, owned by one thread.

A GL context is current in one thread at a time, and the engine runs nodes in threads, so the
context is created by, and only ever used from, a dedicated worker thread (a one-thread
executor): :func:`call` runs a function there and waits, which also serialises all GL work.
Programs are compiled once per process.  A forked child (a Dask worker) gets its own context.

Environment: ``GRAPHKIT_OPENGL_DISABLE`` set to a non-empty value other than ``0`` makes the
OpenGL backends report themselves unavailable (the engine then falls back to numpy, or
refuses a graph that pins ``opengl``).
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

DISABLE_ENV = "GRAPHKIT_OPENGL_DISABLE"


class Unavailable(RuntimeError):
    """OpenGL cannot be used here; the message says why."""


@dataclass
class Runtime:
    gl: Any  # the moderngl module
    ctx: Any
    executor: ThreadPoolExecutor
    programs: dict[tuple[str, str], Any] = field(default_factory=dict)
    renderer: str = "?"  # GL_RENDERER, read on the GL thread at start

    def describe(self) -> str:
        return f"{self.renderer} (OpenGL {self.ctx.version_code})"

    def program(self, vert: str, frag: str) -> Any:
        """The linked program of ``shaders/glsl/<vert>`` + ``<frag>`` (GL thread only)."""
        key = (vert, frag)
        prg = self.programs.get(key)
        if prg is None:
            from graphkit.resources import shader_source

            try:
                vs, fs = shader_source(f"glsl/{vert}"), shader_source(f"glsl/{frag}")
            except FileNotFoundError as e:
                raise Unavailable(str(e)) from None
            try:
                prg = self.ctx.program(vertex_shader=vs, fragment_shader=fs)
            except Exception as e:  # noqa: BLE001 - a compile/link error
                raise Unavailable(f"glsl/{vert} + glsl/{frag} do not build on {self.describe()}: {e}") from None
            self.programs[key] = prg
        return prg

    def call(self, fn: Callable[..., Any], *args, **kw) -> Any:
        """Run ``fn(self, *args, **kw)`` on the GL thread and return its result."""
        return self.executor.submit(fn, self, *args, **kw).result()


_lock = threading.Lock()
_cache: dict[int, Runtime | Unavailable] = {}
PROGRAMS = (("render.vert", "render.frag"), ("depth.vert", "depth.frag"),
            ("screen.vert", "composite.frag"))


def disabled() -> str | None:
    v = os.environ.get(DISABLE_ENV, "").strip()
    if v and v != "0":
        return f"disabled by {DISABLE_ENV}={v}"
    return None


def runtime() -> Runtime:
    """This process's OpenGL runtime; raises :class:`Unavailable` with the reason."""
    why = disabled()
    if why:
        raise Unavailable(why)
    key = os.getpid()
    with _lock:
        rt = _cache.get(key)
        if rt is None:
            rt = _cache[key] = _make()
    if isinstance(rt, Unavailable):
        raise Unavailable(str(rt))  # a fresh exception: the cached one is shared by threads
    return rt


def _make() -> Runtime | Unavailable:
    try:
        import moderngl
    except ImportError as e:
        return Unavailable(f"moderngl is not installed ({e}); `pip install moderngl`")
    ex = ThreadPoolExecutor(max_workers=1, thread_name_prefix="graphkit-opengl")
    try:
        ctx = ex.submit(moderngl.create_standalone_context, backend="egl", require=330).result()
    except Exception as e:  # noqa: BLE001 - no EGL / no driver
        ex.shutdown(wait=False)
        return Unavailable(f"no OpenGL 3.3 context through EGL ({type(e).__name__}: {e}); "
                           "install libegl1 and a Mesa driver (libgl1-mesa-dri)")
    rt = Runtime(moderngl, ctx, ex)
    rt.renderer = ex.submit(lambda: str(ctx.info.get("GL_RENDERER", "?"))).result()
    try:
        for v, f in PROGRAMS:
            rt.call(lambda r, v=v, f=f: r.program(v, f))
    except Unavailable as e:
        return e
    return rt
