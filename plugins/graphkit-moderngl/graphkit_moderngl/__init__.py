"""graphkit-moderngl: an OpenGL backend (moderngl on an EGL standalone context) for Render.

The engine finds this package through the ``graphkit.backends`` entry point declared in
``pyproject.toml``, which points at :data:`BACKENDS`; nothing imports moderngl until a graph
uses the backend.
"""

BACKENDS = {
    "Render/opengl": "graphkit_moderngl.render:RenderGL",
}

__version__ = "0.1.0"
