"""Port types: what flows along the edges of a graph.

Each port type knows how to check a value, split it into (JSON-able meta, list of arrays) for
hashing and storage, and rebuild it from those parts.  Values are plain Python objects:

* :class:`Image`  float32 H×W×C pixels, linear, with a colour-space tag
* :class:`Mask`   float32 H×W weights in [0, 1]
* ``Mesh``        a ``trimesh.Trimesh`` (trimesh is imported only when a mesh is handled)
* :class:`Camera` perspective or orthographic intrinsics + world→camera pose (OpenCV axes: x right,
  y down, z forward) and the world's length unit
* :class:`Light`  a light source (directional or point, world frame, metres) with ambient term
* :class:`Spectrum` values sampled at wavelengths in nm
* :class:`File`   encoded bytes with a file name; ``graphkit run`` writes these into ``--out``
* ``Scalar`` (float), ``Vector`` (1-D float64 array), ``Array`` (any ndarray), ``Json``
* any pydantic model class, used directly as a port type
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Callable, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_serializer, model_validator


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
    """A calibrated camera: ``projection`` "perspective" (pinhole) or "orthographic".

    * perspective: focal lengths ``fx``, ``fy`` in pixels; a camera-frame point (X, Y, Z) lands
      on pixel (fx·X/Z + cx, fy·Y/Z + cy);
    * orthographic: ``pixels_per_m``, the image scale in pixels per metre; (X, Y, Z) lands on
      pixel (s·X + cx, s·Y + cy) with s = pixels_per_m · metres_per_unit pixels per world unit,
      whatever Z; the view direction is the camera's +z everywhere.

    ``world_to_camera`` is a rigid 4×4 row-major matrix (rotation + translation, no scale) from
    the world frame (the frame of the meshes and of every :class:`Light`) to the camera frame.
    Axes follow OpenCV: camera x right, y down, z forward (into the scene), pixel centres at
    integer + 0.5 coordinates.  ``metres_per_unit`` is the world's length unit in metres (1:
    metres, 0.001: a mesh in mm); point-light positions (metres) and the orthographic scale use
    it.  Points at camera depth z ≤ 0 are behind the camera for both projections.

    Every node that projects or casts view rays uses the methods here (``project``, ``rays``,
    ``view_dirs``, ``pixel_matrix``, ``reframed``): the projection maths lives in one place.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")
    width: int = Field(gt=0, description="image width (pixels)")
    height: int = Field(gt=0, description="image height (pixels)")
    projection: Literal["perspective", "orthographic"] = Field(
        "perspective", description="perspective (pinhole: fx, fy) or orthographic (pixels_per_m)")
    fx: Optional[float] = Field(None, gt=0, description="perspective: focal length along x (pixels)")
    fy: Optional[float] = Field(None, gt=0, description="perspective: focal length along y (pixels)")
    pixels_per_m: Optional[float] = Field(None, gt=0, description="orthographic: image scale (pixels per metre)")
    cx: float = Field(description="principal point x (pixels; the image centre is width / 2)")
    cy: float = Field(description="principal point y (pixels)")
    world_to_camera: list[list[float]] = Field(
        default_factory=lambda: np.eye(4).tolist(),
        description="rigid 4×4 world → camera matrix (row-major, OpenCV axes)")
    metres_per_unit: float = Field(1.0, gt=0, description="world length unit in metres (0.001: mm)")

    @field_validator("world_to_camera")
    @classmethod
    def _rigid(cls, v):
        M = np.asarray(v, dtype=np.float64)
        if M.shape != (4, 4):
            raise ValueError(f"world_to_camera must be a 4×4 matrix, got shape {M.shape}")
        if not np.isfinite(M).all():
            raise ValueError("world_to_camera holds NaN or infinite values")
        if not np.allclose(M[3], [0, 0, 0, 1], atol=1e-9):
            raise ValueError(f"world_to_camera's last row must be [0, 0, 0, 1], got {M[3].tolist()}")
        R = M[:3, :3]
        err = float(np.abs(R @ R.T - np.eye(3)).max())
        if err > 1e-6:
            raise ValueError("world_to_camera's 3×3 part is not a rotation (R·Rᵀ differs from I by "
                             f"{err:.2g}): give a rigid pose; set metres_per_unit for the units")
        if np.linalg.det(R) < 0:
            raise ValueError("world_to_camera's 3×3 part is a reflection (det −1), not a rotation")
        return v

    @model_validator(mode="after")
    def _intrinsics(self):
        if self.projection == "perspective":
            missing = [k for k in ("fx", "fy") if getattr(self, k) is None]
            if missing:
                raise ValueError(f"a perspective camera needs {' and '.join(missing)} (focal length "
                                 "in pixels); an orthographic one needs projection: orthographic "
                                 "and pixels_per_m")
            if self.pixels_per_m is not None:
                raise ValueError("pixels_per_m is for orthographic cameras; this one is perspective "
                                 "(set projection: orthographic, or drop pixels_per_m)")
        else:
            if self.pixels_per_m is None:
                raise ValueError("an orthographic camera needs pixels_per_m (image scale, pixels per metre)")
            extra = [k for k in ("fx", "fy") if getattr(self, k) is not None]
            if extra:
                raise ValueError(f"{' and '.join(extra)} are perspective focal lengths; an orthographic "
                                 "camera takes pixels_per_m instead")
        return self

    # -- frames ---------------------------------------------------------------------------

    @property
    def orthographic(self) -> bool:
        return self.projection == "orthographic"

    @property
    def pose(self) -> np.ndarray:
        """The 4×4 world → camera matrix."""
        return np.asarray(self.world_to_camera, dtype=np.float64)

    @property
    def rotation(self) -> np.ndarray:
        """3×3 rotation world → camera (rows: the camera's x, y, z axes in world coordinates)."""
        return self.pose[:3, :3]

    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates (orthographic: the origin of its image plane)."""
        R, t = self.rotation, self.pose[:3, 3]
        return -R.T @ t

    @property
    def forward(self) -> np.ndarray:
        """The camera's viewing axis (+z) in world coordinates (unit)."""
        return self.rotation[2].copy()

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (N×3) → camera-frame points (N×3)."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.rotation.T + self.pose[:3, 3]

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame points (N×3) → world points (N×3)."""
        p = np.asarray(points, dtype=np.float64)
        return (p - self.pose[:3, 3]) @ self.rotation

    def dir_to_camera(self, v) -> np.ndarray:
        """World direction vector(s) (…×3) → camera frame."""
        return np.asarray(v, dtype=np.float64) @ self.rotation.T

    def dir_to_world(self, v) -> np.ndarray:
        """Camera-frame direction vector(s) (…×3) → world frame."""
        return np.asarray(v, dtype=np.float64) @ self.rotation

    # -- projection -----------------------------------------------------------------------

    @property
    def scale(self) -> float:
        """Orthographic: pixels per world unit (pixels_per_m · metres_per_unit)."""
        if not self.orthographic:
            raise ValueError("scale is defined for orthographic cameras only")
        return float(self.pixels_per_m) * self.metres_per_unit

    @property
    def K(self) -> np.ndarray:
        """3×3 pinhole intrinsics (perspective cameras only; see :meth:`pixel_matrix`)."""
        if self.orthographic:
            raise ValueError("an orthographic camera has no pinhole matrix K; use pixel_matrix()")
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def pixel_matrix(self) -> np.ndarray:
        """3×4 P with (u·w, v·w, w) = P · (X, Y, Z, 1) for camera-frame points: w = Z
        (perspective) or 1 (orthographic)."""
        if self.orthographic:
            s = self.scale
            return np.array([[s, 0, 0, self.cx], [0, s, 0, self.cy], [0, 0, 0, 1.0]])
        return np.array([[self.fx, 0, self.cx, 0], [0, self.fy, self.cy, 0], [0, 0, 1.0, 0]])

    def world_pixel_matrix(self) -> np.ndarray:
        """3×4 matrix from world points (homogeneous) to homogeneous pixels (pixel_matrix · pose)."""
        return self.pixel_matrix() @ self.pose

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N×3) → pixel coordinates (N×2) and camera-frame depth z (N)."""
        p = self.to_camera(points)
        z = p[:, 2]
        if self.orthographic:
            s = self.scale
            return np.stack([s * p[:, 0] + self.cx, s * p[:, 1] + self.cy], 1), z
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], 1)
        return uv, z

    def ray_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """(O, D), 3×3 each: the world ray through pixel (x, y) starts at O·(x, y, 1) and runs
        along D·(x, y, 1) (not normalised).  Perspective: every ray starts at the centre;
        orthographic: every ray runs along the camera's +z."""
        Rt = self.rotation.T
        C = self.position
        if self.orthographic:
            s = self.scale
            A = np.array([[1 / s, 0, -self.cx / s], [0, 1 / s, -self.cy / s], [0, 0, 0.0]])
            O = Rt @ A
            O[:, 2] += C
            D = np.zeros((3, 3))
            D[:, 2] = self.forward
            return O, D
        O = np.zeros((3, 3))
        O[:, 2] = C
        return O, Rt @ np.linalg.inv(self.K)

    def rays(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N×2, centres at +0.5) → world ray origins (N×3) and unit
        directions (N×3) into the scene."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        h = np.column_stack([xy, np.ones(len(xy))])
        O, D = self.ray_matrices()
        d = h @ D.T
        return h @ O.T, d / np.linalg.norm(d, axis=1, keepdims=True)

    def view_dirs(self, points: np.ndarray) -> np.ndarray:
        """Unit directions from world points (N×3) towards the viewer: towards the centre
        (perspective) or −forward (orthographic)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.orthographic:
            return np.broadcast_to(-self.forward, p.shape).copy()
        v = self.position[None, :] - p
        n = np.linalg.norm(v, axis=1, keepdims=True)
        return np.divide(v, n, out=np.zeros_like(v), where=n > 0)

    def units_per_pixel(self, depth) -> np.ndarray:
        """Size of one pixel (world units) on a fronto-parallel surface at camera depth ``depth``."""
        d = np.asarray(depth, dtype=np.float64)
        if self.orthographic:
            return np.full_like(d, 1.0 / self.scale)
        return d / np.sqrt(self.fx * self.fy)

    def reframed(self, width: int, height: int, zoom: float, centre: tuple[float, float]) -> "Camera":
        """The same pose, the image magnified ``zoom`` times about pixel ``centre`` of this
        camera, which lands at the middle of a ``width``×``height`` image."""
        k = float(zoom)
        cx = (self.cx - centre[0]) * k + width / 2
        cy = (self.cy - centre[1]) * k + height / 2
        upd: dict = {"width": int(width), "height": int(height), "cx": cx, "cy": cy}
        if self.orthographic:
            upd["pixels_per_m"] = self.pixels_per_m * k
        else:
            upd["fx"], upd["fy"] = self.fx * k, self.fy * k
        return Camera.model_validate({**self.model_dump(), **upd})

    # -- lights -----------------------------------------------------------------------------

    def light_to_world(self, light: "Light") -> "Light":
        """A Light given in this camera's frame (directions in camera axes, a point light's
        position in metres from the camera centre) → the same light in the world frame."""
        return _move_light(light, self.rotation.T, self.position * self.metres_per_unit)

    def light_to_camera(self, light: "Light") -> "Light":
        """A world-frame Light → this camera's frame (inverse of :meth:`light_to_world`)."""
        R = self.rotation
        return _move_light(light, R, -(R @ self.position) * self.metres_per_unit)


def _move_light(light: "Light", R: np.ndarray, t_m: np.ndarray) -> "Light":
    d = R @ np.asarray(light.direction, np.float64)
    p = R @ np.asarray(light.position, np.float64) + t_m
    return light.model_copy(update={"direction": tuple(float(x) for x in d),
                                    "position": tuple(float(x) for x in p)})


_LIGHT_SIZES = ("radius_m", "angular_radius_deg")  # Light's size fields, dropped while 0


class Light(BaseModel):
    """A light source in the WORLD frame (the meshes' frame; a Camera maps it to its own).

    * ``directional``: ``direction`` is the unit vector from the surface towards the light;
      ``color`` × ``intensity`` is the irradiance at normal incidence in flash units (1 = what
      the photo's flash gives the face).
    * ``point``: ``position`` in metres in the world frame (world coordinates ×
      Camera.metres_per_unit); ``color`` × ``intensity`` is the radiant intensity in flash
      units × m²: it gives the irradiance E = I·cos θ / d² (d in metres) — always, there is no
      opt-in fall-off.  A point light of intensity d² at d metres lights a surface facing it like
      a directional light of intensity 1.  ``direction`` is informative (from the subject towards
      the light; ShininessFromSaturation reads it).
    * ``ambient``: linear-RGB ambient term in flash units (already multiplied by its intensity;
      a white surface of diffuse colour k shows k·ambient).

    * the light's size, for soft shadows: ``radius_m``, a point light's radius as a sphere
      (metres); ``angular_radius_deg``, a directional light's angular radius as a disc (the sun
      is 0.27°).  0 (the default) is a point or a parallel light: hard shadows.  A size is left
      out of the light's serialised form while it is 0, so lights without one keep their bytes.

    ``color`` is linear RGB.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")
    kind: str = Field("directional", pattern="^(directional|point)$")
    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = Field(1.0, ge=0)
    ambient: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius_m: float = Field(0.0, ge=0, allow_inf_nan=False)
    angular_radius_deg: float = Field(0.0, ge=0, lt=90)

    @model_validator(mode="after")
    def _size_fits_kind(self):
        if self.radius_m and self.kind != "point":
            raise ValueError("radius_m is a point light's size; a directional light's is angular_radius_deg")
        if self.angular_radius_deg and self.kind != "directional":
            raise ValueError("angular_radius_deg is a directional light's size; a point light's is radius_m")
        return self

    @model_serializer(mode="wrap")
    def _without_zero_size(self, handler):
        out = handler(self)
        for k in _LIGHT_SIZES:
            if out.get(k) == 0:
                del out[k]
        return out

    @property
    def has_size(self) -> bool:
        """Whether the light has a size (soft shadows)."""
        return self.radius_m > 0 or self.angular_radius_deg > 0

    def in_world_units(self, metres_per_unit: float) -> "Light":
        """The light with a point light's position and intensity in world units of
        ``metres_per_unit`` metres (position / u, intensity / u², so I/d² is unchanged)."""
        if self.kind != "point" or metres_per_unit == 1.0:
            return self
        u = float(metres_per_unit)
        return self.model_copy(update={"position": tuple(float(x) / u for x in self.position),
                                       "intensity": self.intensity / (u * u),
                                       "radius_m": self.radius_m / u})


# --------------------------------------------------------------------------------------------
# port types


@dataclass(frozen=True)
class PortType:
    """How the engine checks, hashes and stores values of one kind.

    ``name`` is the short name users see; ``qualname`` (module.qualname of the value class, by
    default the module of ``check`` plus ``name``) identifies the type: two plugins that each
    define an ``Image`` are different types.  Cache keys and value digests use ``name`` only."""

    name: str
    check: Callable[[Any], str | None]  # None if ok, else what is wrong
    to_parts: Callable[[Any], tuple[dict, list[np.ndarray]]]
    from_parts: Callable[[dict, list[np.ndarray]], Any]
    export_ext: str = ".json"  # how `graphkit run` writes a non-File output
    doc: str = ""
    qualname: str = ""

    def __post_init__(self):
        if not self.qualname:
            object.__setattr__(self, "qualname", f"{getattr(self.check, '__module__', None) or __name__}.{self.name}")

    def accepts(self, other: "PortType") -> bool:
        return self.qualname == other.qualname or self.qualname == ANY.qualname

    def __str__(self) -> str:
        return self.name


def mismatch_names(want: PortType, have: PortType) -> tuple[str, str]:
    """How to name two port types that do not match: their short names, or their qualified
    names when the short ones are the same (two plugins' ``Image``)."""
    if want.name == have.name:
        return want.qualname, have.qualname
    return want.name, have.name


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
        qualname=f"{cls.__module__}.{cls.__qualname__}",
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
