"""The per-process OpenGL state: one EGL standalone context, owned by one thread.

A GL context is current in one thread at a time, and the engine runs nodes in threads, so the
context is created by, and only ever used from, a dedicated worker thread (a one-thread
executor): :func:`call` runs a function there and waits, which also serialises all GL work.
Programs are compiled once per process (per set of ``#define`` values: the shaders of
``shaders/glsl/`` go through :mod:`graphkit.glsl`, the preprocessor shared with the studio's
WebGL2 view), and the GL objects a render needs (vertex/index buffers, textures, render
targets, the passes' results) are kept in :attr:`Runtime.objects`, a bounded
least-recently-used store keyed by the content of what they hold, between calls and between
nodes of one run.  A forked child (a Dask worker) gets its own context.

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
    programs: dict[tuple, Any] = field(default_factory=dict)
    renderer: str = "?"  # GL_RENDERER, read on the GL thread at start
    max_texture_size: int = 4096
    objects: "GLObjects" = field(default_factory=lambda: GLObjects())

    def describe(self) -> str:
        return f"{self.renderer} (OpenGL {self.ctx.version_code})"

    def program(self, vert: str, frag: str, defines: dict | None = None) -> Any:
        """The linked program of ``shaders/glsl/<vert>`` + ``<frag>`` with ``defines``
        (GLSL 3.30 through :func:`graphkit.glsl.source`; GL thread only)."""
        key = (vert, frag, tuple(sorted((defines or {}).items())))
        prg = self.programs.get(key)
        if prg is None:
            from graphkit.glsl import GlslError, source

            try:
                vs, fs = source(vert, "330", defines), source(frag, "330", defines)
            except GlslError as e:
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


class GLObjects:
    """GL objects kept between calls (GL thread only): ``get(key, make, nbytes)`` returns the
    object(s) stored under ``key`` or makes them; the least recently used entries are released
    once more than ``budget`` bytes (GPU memory, as estimated by the caller) or ``max_entries``
    entries are held, never one used since the last :meth:`begin` (the current render's).
    An entry is a GL object, a tuple/list/dict of them, or plain data."""

    def __init__(self, budget: int = 1 << 30, max_entries: int = 64):
        from collections import OrderedDict

        self.budget, self.max_entries = budget, max_entries
        self._d: OrderedDict = OrderedDict()
        self.bytes = 0
        self.hits = self.misses = 0
        self._gen = 0

    def begin(self):
        """A new render starts: what it uses from now on is kept until the next begin()."""
        self._gen += 1

    def get(self, key, make: Callable[[], Any], nbytes: int = 0):
        hit = self._d.get(key)
        if hit is not None:
            self._d.move_to_end(key)
            self._d[key] = (hit[0], hit[1], self._gen)
            self.hits += 1
            return hit[0]
        self.misses += 1
        while self._d and (self.bytes + nbytes > self.budget or len(self._d) >= self.max_entries):
            old_key, (_, _, gen) = next(iter(self._d.items()))
            if gen == self._gen:
                break  # everything older is in use by this render
            self.drop(old_key)
        obj = make()
        self._d[key] = (obj, nbytes, self._gen)
        self.bytes += nbytes
        return obj

    def peek(self, key):
        """The object stored under ``key`` (marked used by this render), or None."""
        hit = self._d.get(key)
        if hit is None:
            return None
        self._d.move_to_end(key)
        self._d[key] = (hit[0], hit[1], self._gen)
        return hit[0]

    def put(self, key, obj, nbytes: int = 0):
        """Store ``obj`` under ``key`` (releasing what was there)."""
        self.drop(key)
        self.get(key, lambda: obj, nbytes)

    def drop(self, key):
        hit = self._d.pop(key, None)
        if hit is not None:
            self.bytes -= hit[1]
            _release(hit[0])

    def clear(self):
        for k in list(self._d):
            self.drop(k)

    def __len__(self):
        return len(self._d)


def _release(obj):
    if isinstance(obj, (list, tuple)):
        for o in reversed(obj):
            _release(o)
    elif isinstance(obj, dict):
        for o in reversed(list(obj.values())):
            _release(o)
    elif hasattr(obj, "release") and callable(obj.release):
        obj.release()


_lock = threading.Lock()
_cache: dict[int, Runtime | Unavailable] = {}
# built when the runtime starts, so that a driver that cannot compile them is reported as
# unavailable (the other variants, per define, are built when first used)
PROGRAMS = (("depth.vert", "depth.frag", None), ("gbuffer.vert", "gbuffer.frag", {"DETAIL": 1}),
            ("screen.vert", "shade.frag", {"N_LIGHTS": 1, "SHADOWS": 1, "EYES": 1}))


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
    rt.max_texture_size = int(ex.submit(lambda: ctx.info.get("GL_MAX_TEXTURE_SIZE", 4096)).result())
    try:
        for v, f, d in PROGRAMS:
            rt.call(lambda r, v=v, f=f, d=d: r.program(v, f, d))
    except Unavailable as e:
        return e
    return rt
