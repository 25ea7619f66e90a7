"""Port types of the Loscos 2000 nodes: small dataclasses of numpy arrays.

:func:`dataclass_port` turns a dataclass whose fields are numpy arrays or JSON-able values into
a :class:`graphkit.PortType` (arrays are hashed and stored as arrays, the rest as JSON meta).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from graphkit import PortType


def dataclass_port(cls, doc: str = "") -> PortType:
    names = [f.name for f in dataclasses.fields(cls)]

    def check(v):
        return None if isinstance(v, cls) else f"expected {cls.__name__}, got {type(v).__name__}"

    optional = {f.name for f in dataclasses.fields(cls) if f.default is None}

    def to_parts(v):
        arrays, meta = [], {"arrays": [], "json": {}}
        for n in names:
            x = getattr(v, n)
            if x is None and n in optional:
                continue  # a field left at its None default is not stored (older values' bytes)
            if isinstance(x, np.ndarray):
                meta["arrays"].append(n)
                arrays.append(np.ascontiguousarray(x))
            else:
                meta["json"][n] = x
        return meta, arrays

    def from_parts(meta, arrays):
        kw = dict(meta["json"])
        kw.update(zip(meta["arrays"], arrays))
        return cls(**kw)

    return PortType(cls.__name__, check, to_parts, from_parts, ".json",
                    doc or (cls.__doc__ or "").strip().split("\n")[0])


@dataclass(eq=False)
class RoomScene:
    """Polygons (planar parallelograms, or triangles) of a real scene with reflectances and emitters.

    verts (P,4,3) in metres, vertices counter-clockwise seen from the front side; a triangle
    (a, b, c) is written (a, b, c, c) (geometry.is_triangle);
    reflectance (P,3) diffuse albedo (linear RGB, unitless); emittance (P,3) exitant
    radiosity of emitters in W/m² (= π × radiance); light (P,) name of the light a polygon
    belongs to ("" if none); virtual (P,) bool — inserted, not in the photograph;
    emit_given (P,) bool — False on the polygons of a light whose emittance the scene file
    leaves to be estimated from the photograph (their emittance is then 0 here).
    """

    names: list
    verts: np.ndarray
    reflectance: np.ndarray
    emittance: np.ndarray
    light: list
    virtual: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    emit_given: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def __post_init__(self):
        self.verts = np.asarray(self.verts, np.float64).reshape(-1, 4, 3)
        P = len(self.verts)
        self.reflectance = np.asarray(self.reflectance, np.float64).reshape(P, 3)
        self.emittance = np.asarray(self.emittance, np.float64).reshape(P, 3)
        self.names = list(self.names)
        self.light = list(self.light)
        if len(self.virtual) != P:
            self.virtual = np.zeros(P, bool)
        self.virtual = np.asarray(self.virtual, bool)
        if len(self.emit_given) != P:
            self.emit_given = np.ones(P, bool)
        self.emit_given = np.asarray(self.emit_given, bool)

    @property
    def light_names(self) -> list[str]:
        out = []
        for n in self.light:
            if n and n not in out:
                out.append(n)
        return out

    def light_given(self) -> np.ndarray:
        """(S,) bool per light (light_names order): the scene file gives its emittance."""
        return np.array([bool(self.emit_given[self.light.index(s)]) for s in self.light_names],
                        bool)


@dataclass(eq=False)
class Projection:
    """The photograph projected onto the polygons from the fixed viewpoint (§3, §4).

    textures (P,R,R,3): linear RGB radiance per texel (s, t) of each polygon; coverage (P,R,R)
    1 where the texel is seen by the camera (and sampled from pixels that see only its
    polygon); pix_poly (H,W) polygon seen at each pixel centre (-1: none); pix_st (H,W,2) its
    polygon coordinates; sub_pix (n,) the flat indices of the pixels that see more than one
    polygon, sub_poly (n,k²) and sub_st (n,k²,2) what their k×k subsamples see; em_pix,
    em_poly, em_cover, em_st (m,): the exact share of pixel em_pix covered by emitter
    polygon em_poly, and the (s, t) on it at the centroid of that share; em_radiance (P,3)
    each emitter's radiance measured in the photograph from those pixels (NaN: unseen),
    em_seen (P,) the area it covers, in pixels.
    """

    textures: np.ndarray
    coverage: np.ndarray
    pix_poly: np.ndarray
    pix_st: np.ndarray
    sub_pix: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    sub_poly: np.ndarray = field(default_factory=lambda: np.zeros((0, 1), np.int64))
    sub_st: np.ndarray = field(default_factory=lambda: np.zeros((0, 1, 2)))
    em_pix: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    em_poly: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    em_cover: np.ndarray = field(default_factory=lambda: np.zeros(0))
    em_st: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    em_radiance: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    em_seen: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(eq=False)
class RadiositySolution:
    """A hierarchical radiosity solution with per-light responses (§2.3, §4, §5).

    Hierarchy arrays (see hierarchy.Hierarchy) plus, per leaf: rho (L,3) reflectance,
    T (L,3) mean texture radiance (NaN where unseen), resp (L,S,3) radiosity for unit
    emittance of each light S (linearity of radiosity in emittances), resp_H and resp_Hu
    (L,S,3) irradiance with and without occlusion for the same unit emittances;
    emit (S,3) the emittance of each light in W/m²; lights: names; info: how it was made
    (info["lights"]: per light its emittance, where it came from, the eq. 2 start).
    """

    P_o: np.ndarray
    P_u: np.ndarray
    P_v: np.ndarray
    poly: np.ndarray
    level: np.ndarray
    ij: np.ndarray
    parent: np.ndarray
    child0: np.ndarray
    recv: np.ndarray
    send: np.ndarray
    F: np.ndarray
    V: np.ndarray
    C: np.ndarray
    rho: np.ndarray
    T: np.ndarray
    resp: np.ndarray
    resp_H: np.ndarray
    resp_Hu: np.ndarray
    emit: np.ndarray
    lights: list
    info: dict = field(default_factory=dict)
    P_tri: np.ndarray | None = None  # (P,) bool triangle polygons, (N,) bool flipped
    flip: np.ndarray | None = None  # elements: None where the scene has no triangle
    #: cluster links (hierarchy.Hierarchy.CLUSTER_ARRAYS): None where links start at polygons
    cl_V: np.ndarray | None = None
    cl_r: np.ndarray | None = None
    cl_rw: np.ndarray | None = None
    cl_s: np.ndarray | None = None
    cl_sw: np.ndarray | None = None

    def hierarchy(self):
        from .hierarchy import Hierarchy

        opt = {k: getattr(self, k) for k in Hierarchy.TRI_ARRAYS + Hierarchy.CLUSTER_ARRAYS
               if getattr(self, k) is not None}
        return Hierarchy(**{k: getattr(self, k) for k in Hierarchy.ARRAYS}, **opt)

    @property
    def leaves(self):
        return np.flatnonzero((self.child0 < 0) & (self.parent != -2))

    def B(self, emit=None):
        """Leaf radiosity (L,3) in W/m² for emittances (S,3) (default: the solved ones)."""
        e = self.emit if emit is None else np.asarray(emit, np.float64)
        return np.einsum("lsc,sc->lc", self.resp, e)

    def H(self, emit=None, unoccluded=False):
        e = self.emit if emit is None else np.asarray(emit, np.float64)
        return np.einsum("lsc,sc->lc", self.resp_Hu if unoccluded else self.resp_H, e)


@dataclass(eq=False)
class Unoccluded:
    """Unoccluded illumination (§4.2–4.3): per leaf the texture modulation
    T_final / T_orig (L,3), D_final responses (L,S,3) — display correction per unit
    emittance, and the occlusion class of each leaf (L,) (1 = occluded from a real light)."""

    modulation: np.ndarray
    resp_D: np.ndarray
    occluded: np.ndarray
    reference: np.ndarray  # (L,) leaf index of the reference patch (-1: none)


ROOM_SCENE = dataclass_port(RoomScene)
PROJECTION = dataclass_port(Projection)
RADIOSITY = dataclass_port(RadiositySolution)
UNOCCLUDED = dataclass_port(Unoccluded)
