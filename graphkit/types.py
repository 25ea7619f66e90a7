"""Port types: what flows along the edges of a graph.

Each port type knows how to check a value, split it into (JSON-able meta, list of arrays) for
hashing and storage, and rebuild it from those parts.  Values are plain Python objects:

* :class:`Image`  float32 H×W×C pixels, linear, with a colour-space tag
* :class:`Mask`   float32 H×W weights in [0, 1]
* ``Mesh``        a ``trimesh.Trimesh`` (trimesh is imported only when a mesh is handled)
* :class:`Camera` pinhole intrinsics + world→camera pose (OpenCV axes: x right, y down, z forward)
* :class:`Light`  a light source (directional or point) with ambient term
* :class:`Spectrum` values sampled at wavelengths in nm
* :class:`File`   encoded bytes with a file name; ``graphkit run`` writes these into ``--out``
* ``Scalar`` (float), ``Vector`` (1-D float64 array), ``Array`` (any ndarray), ``Json``
* any pydantic model class, used directly as a port type
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


# --------------------------------------------------------------------------------------------
# value classes


@dataclass(eq=False)
class Image:
    """Float32 H×W×C pixels; linear values unless ``colorspace`` says otherwise."""

    pixels: np.ndarray
    colorspace: str = "lin_srgb"

    def __post_init__(self):
        self.pixels = np.ascontiguousarray(self.pixels, dtype=np.float32)
        if self.pixels.ndim == 2:
            self.pixels = self.pixels[:, :, None]

    @property
    def height(self) -> int:
        return self.pixels.shape[0]

    @property
    def width(self) -> int:
        return self.pixels.shape[1]

    @property
    def channels(self) -> int:
        return self.pixels.shape[2]

    def size_str(self) -> str:
        return f"{self.width}×{self.height}×{self.channels}"


@dataclass(eq=False)
class Mask:
    """Float32 H×W weights in [0, 1] (1 = inside)."""

    alpha: np.ndarray

    def __post_init__(self):
        a = np.asarray(self.alpha)
        if a.ndim == 3 and a.shape[2] == 1:
            a = a[:, :, 0]
        self.alpha = np.ascontiguousarray(a, dtype=np.float32)

    @property
    def height(self) -> int:
        return self.alpha.shape[0]

    @property
    def width(self) -> int:
        return self.alpha.shape[1]


@dataclass(eq=False)
class Spectrum:
    """Values sampled at ``wavelengths`` (nm)."""

    wavelengths: np.ndarray
    values: np.ndarray
    unit: str = ""

    def __post_init__(self):
        self.wavelengths = np.ascontiguousarray(self.wavelengths, dtype=np.float64)
        self.values = np.ascontiguousarray(self.values, dtype=np.float64)


@dataclass(eq=False)
class File:
    """An encoded file.  ``name`` is a relative path inside the run's ``--out`` folder."""

    name: str
    data: bytes
    metadata: dict = field(default_factory=dict)


class Camera(BaseModel):
    """Pinhole camera. Intrinsics in pixels; ``world_to_camera`` is a 4×4 row-major matrix.

    Axes follow OpenCV: camera x right, y down, z forward (into the scene), pixel centres at
    integer + 0.5 coordinates.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    world_to_camera: list[list[float]] = Field(
        default_factory=lambda: np.eye(4).tolist()
    )

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def pose(self) -> np.ndarray:
        return np.asarray(self.world_to_camera, dtype=np.float64)

    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return np.linalg.inv(self.pose)[:3, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N×3) → pixel coordinates (N×2) and camera-space depth z (N)."""
        p = np.asarray(points, dtype=np.float64) @ self.pose[:3, :3].T + self.pose[:3, 3]
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], 1)
        return uv, z


class Light(BaseModel):
    """A light source. Directions point *from the surface towards the light* (unit, world).

    ``color`` is linear RGB, ``intensity`` a scale on it; ``ambient`` is the linear-RGB
    ambient radiance (already multiplied by its intensity).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")
    kind: str = Field("directional", pattern="^(directional|point)$")
    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = Field(1.0, ge=0)
    ambient: tuple[float, float, float] = (0.0, 0.0, 0.0)


# --------------------------------------------------------------------------------------------
# port types


@dataclass(frozen=True)
class PortType:
    """How the engine checks, hashes and stores values of one kind."""

    name: str
    check: Callable[[Any], str | None]  # None if ok, else what is wrong
    to_parts: Callable[[Any], tuple[dict, list[np.ndarray]]]
    from_parts: Callable[[dict, list[np.ndarray]], Any]
    export_ext: str = ".json"  # how `graphkit run` writes a non-File output
    doc: str = ""

    def accepts(self, other: "PortType") -> bool:
        return self.name == other.name or self.name == "Any"

    def __str__(self) -> str:
        return self.name


def _is_finite_float(x) -> bool:
    return isinstance(x, (int, float, np.floating, np.integer)) and not isinstance(x, bool)


def _check_image(v):
    if not isinstance(v, Image):
        return f"expected an Image, got {type(v).__name__}"
    if v.pixels.ndim != 3 or v.pixels.dtype != np.float32:
        return f"Image pixels must be float32 H×W×C, got {v.pixels.dtype} {v.pixels.shape}"
    return None


def _check_mask(v):
    if not isinstance(v, Mask):
        return f"expected a Mask, got {type(v).__name__}"
    if v.alpha.ndim != 2:
        return f"Mask must be H×W, got shape {v.alpha.shape}"
    return None


def _check_mesh(v):
    import trimesh

    if not isinstance(v, trimesh.Trimesh):
        return f"expected a trimesh.Trimesh, got {type(v).__name__}"
    return None


def _mesh_to_parts(m):
    arrays = [np.ascontiguousarray(m.vertices, np.float64), np.ascontiguousarray(m.faces, np.int64)]
    meta: dict = {"attrs": []}
    uv = getattr(m.visual, "uv", None)
    if uv is not None:
        arrays.append(np.ascontiguousarray(uv, np.float64))
        meta["attrs"].append("uv")
    for name in sorted(m.vertex_attributes):
        arrays.append(np.ascontiguousarray(m.vertex_attributes[name]))
        meta["attrs"].append("va:" + name)
    return meta, arrays


def _mesh_from_parts(meta, arrays):
    import trimesh

    m = trimesh.Trimesh(vertices=arrays[0], faces=arrays[1], process=False)
    for name, arr in zip(meta.get("attrs", []), arrays[2:]):
        if name == "uv":
            m.visual = trimesh.visual.TextureVisuals(uv=arr)
        elif name.startswith("va:"):
            m.vertex_attributes[name[3:]] = arr
    return m


def _model_port(cls: type[BaseModel]) -> PortType:
    def check(v):
        return None if isinstance(v, cls) else f"expected {cls.__name__}, got {type(v).__name__}"

    return PortType(
        name=cls.__name__,
        check=check,
        to_parts=lambda v: ({"model": v.model_dump(mode="json")}, []),
        from_parts=lambda meta, arrays: cls.model_validate(meta["model"]),
        doc=(cls.__doc__ or "").strip().split("\n")[0],
    )


def _check_json(v):
    try:
        json.dumps(v, allow_nan=False)
    except (TypeError, ValueError) as e:
        return f"not JSON-able: {e}"
    return None


IMAGE = PortType(
    "Image",
    _check_image,
    lambda v: ({"colorspace": v.colorspace}, [v.pixels]),
    lambda meta, a: Image(a[0], meta["colorspace"]),
    ".npy",
    "float32 H×W×C pixels, linear, with a colour-space tag",
)
MASK = PortType(
    "Mask", _check_mask, lambda v: ({}, [v.alpha]), lambda meta, a: Mask(a[0]), ".npy",
    "float32 H×W weights in [0, 1]",
)
MESH = PortType("Mesh", _check_mesh, _mesh_to_parts, _mesh_from_parts, ".ply",
                "triangle mesh (trimesh.Trimesh)")
SPECTRUM = PortType(
    "Spectrum",
    lambda v: None if isinstance(v, Spectrum) else f"expected a Spectrum, got {type(v).__name__}",
    lambda v: ({"unit": v.unit}, [v.wavelengths, v.values]),
    lambda meta, a: Spectrum(a[0], a[1], meta["unit"]),
    ".npy",
    "values sampled at wavelengths in nm",
)
FILE = PortType(
    "File",
    lambda v: None if isinstance(v, File) else f"expected a File, got {type(v).__name__}",
    lambda v: ({"name": v.name, "metadata": v.metadata}, [np.frombuffer(v.data, np.uint8)]),
    lambda meta, a: File(meta["name"], a[0].tobytes(), meta.get("metadata", {})),
    "",
    "an encoded file written into --out",
)
SCALAR = PortType(
    "Scalar",
    lambda v: None if _is_finite_float(v) else f"expected a number, got {type(v).__name__}",
    lambda v: ({"value": float(v).hex()}, []),
    lambda meta, a: float.fromhex(meta["value"]),
    ".json",
    "a float",
)
VECTOR = PortType(
    "Vector",
    lambda v: None if isinstance(v, np.ndarray) and v.ndim == 1 else "expected a 1-D array",
    lambda v: ({}, [np.ascontiguousarray(v, np.float64)]),
    lambda meta, a: a[0],
    ".npy",
    "1-D float64 array",
)
ARRAY = PortType(
    "Array",
    lambda v: None if isinstance(v, np.ndarray) else f"expected an ndarray, got {type(v).__name__}",
    lambda v: ({}, [np.ascontiguousarray(v)]),
    lambda meta, a: a[0],
    ".npy",
    "any numpy array",
)
JSON = PortType("Json", _check_json, lambda v: ({"json": v}, []), lambda m, a: m["json"], ".json",
                "any JSON-able value")
ANY = PortType("Any", lambda v: None, lambda v: ({}, []), lambda m, a: None, ".json",
               "accepts any type (input ports only)")

# Markers usable in node declarations (``inputs = {"mesh": Mesh}``).
Mesh = MESH
Scalar = SCALAR
Vector = VECTOR
Array = ARRAY
Json = JSON

_BY_CLASS: dict[type, PortType] = {Image: IMAGE, Mask: MASK, Spectrum: SPECTRUM, File: FILE}
BUILTIN_PORT_TYPES: dict[str, PortType] = {
    p.name: p for p in (IMAGE, MASK, MESH, SPECTRUM, FILE, SCALAR, VECTOR, ARRAY, JSON, ANY)
}
_MODEL_PORTS: dict[type, PortType] = {}


def port_type(decl: Any) -> PortType:
    """Turn a port declaration (a value class, a PortType or a pydantic model) into a PortType."""
    if isinstance(decl, PortType):
        return decl
    if decl in _BY_CLASS:
        return _BY_CLASS[decl]
    if decl is float:
        return SCALAR
    if isinstance(decl, type) and issubclass(decl, BaseModel):
        if decl not in _MODEL_PORTS:
            _MODEL_PORTS[decl] = _model_port(decl)
        return _MODEL_PORTS[decl]
    raise TypeError(f"not a port type: {decl!r}")


def finite_or_message(arr: np.ndarray) -> str | None:
    """None if every value is finite, else a short description of the bad values."""
    if arr.dtype.kind != "f":
        return None
    ok = np.isfinite(arr)
    if ok.all():
        return None
    bad = np.argwhere(~ok)
    n_nan = int(np.isnan(arr).sum())
    n_inf = int(bad.shape[0] - n_nan)
    first = tuple(int(i) for i in bad[0])
    return f"{n_nan} NaN and {n_inf} Inf values (first at index {first})"


__all__ = [
    "Image", "Mask", "Mesh", "Camera", "Light", "Spectrum", "File", "Scalar", "Vector",
    "Array", "Json", "PortType", "port_type", "finite_or_message",
]
