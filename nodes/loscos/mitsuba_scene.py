"""A Mitsuba 3 scene dict → the Loscos scene file (``loscos_scene: 1``, see scene.py).

    from nodes.loscos.mitsuba_scene import scene_file, write_scene_file
    doc = scene_file(mi_dict, photo="room.exr")        # a dict, ready for yaml.safe_dump
    write_scene_file(mi_dict, "room.yaml", photo="room.exr")

What it takes (anything else raises :class:`MitsubaSceneError`, naming the entry):

* shapes ``rectangle`` ([-1,1]² in z = 0, normal +z), ``cube`` ([-1,1]³, outward), ``obj`` and
  ``ply`` meshes (read with trimesh; coplanar triangle pairs that form a parallelogram are
  merged — a mesh exported from quads pairs up —, the rest stay triangles: meshes.py), each with ``to_world`` (a Mitsuba
  transform, a 4×4 array or nested lists) and ``flip_normals``;
* BSDFs ``diffuse`` (rgb or uniform reflectance), also inside ``twosided``, inline or by
  ``{"type": "ref", "id": …}``; a shape without a BSDF is Mitsuba's default grey 0.5;
* ``area`` emitters on shapes: the shape becomes a light named by its key, emittance
  π × radiance in W/m² (left out with ``emittance=False``: RadiositySolve then estimates it);
* one ``perspective`` sensor: ``to_world`` (position, view direction, up), ``fov`` with any
  ``fov_axis``, the film's width and height.

Units are Mitsuba's scene units (metres for the project's scenes).  Mitsuba itself is not
needed unless the dict holds Mitsuba transform objects.
"""
from __future__ import annotations

import os

import numpy as np

RECT = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
SHAPES = ("rectangle", "cube", "obj", "ply")
IGNORED = ("integrator", "sampler", "film", "rfilter")


class MitsubaSceneError(ValueError):
    """A Mitsuba scene dict entry that has no counterpart in the Loscos scene file."""


def matrix(t, where: str) -> np.ndarray:
    """A 4×4 float array from a Mitsuba transform (``.matrix``), an array or nested lists."""
    if t is None:
        return np.eye(4)
    m = np.asarray(getattr(t, "matrix", t), float)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise MitsubaSceneError(f"{where}: to_world must be a 4×4 transform")
    return m


def _apply(M: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ M[:3, :3].T + M[:3, 3]


def _rgb(v, where: str) -> list[float]:
    """An rgb/spectrum value (dict, number or 3 numbers) → 3 floats."""
    if isinstance(v, dict):
        if v.get("type") not in ("rgb", "spectrum", None):
            raise MitsubaSceneError(f"{where}: a '{v.get('type')}' texture has no counterpart "
                                    "(the scene file takes one colour per polygon)")
        v = v.get("value")
    a = np.asarray(v, float).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise MitsubaSceneError(f"{where}: expected an rgb value, got {v!r}")
    return [float(x) for x in a]


def _albedo(bsdf, defs: dict, where: str) -> list[float]:
    if bsdf is None:
        return [0.5, 0.5, 0.5]
    if bsdf.get("type") == "ref":
        if bsdf.get("id") not in defs:
            raise MitsubaSceneError(f"{where}: BSDF reference '{bsdf.get('id')}' is not defined")
        bsdf = defs[bsdf["id"]]
    if bsdf.get("type") == "twosided":
        inner = [v for k, v in bsdf.items() if isinstance(v, dict) and k != "type"]
        if len(inner) != 1:
            raise MitsubaSceneError(f"{where}: a twosided BSDF needs one inner BSDF")
        return _albedo(inner[0], defs, where)
    if bsdf.get("type") != "diffuse":
        raise MitsubaSceneError(f"{where}: BSDF '{bsdf.get('type')}' has no counterpart "
                                "(Loscos 2000 models diffuse surfaces: use 'diffuse')")
    return _rgb(bsdf.get("reflectance", 0.5), f"{where}.bsdf.reflectance")


def _shape_polygons(key: str, sh: dict, base_dir: str) -> np.ndarray:
    kind = sh["type"]
    M = matrix(sh.get("to_world"), key)
    if kind == "rectangle":
        polys = _apply(M, RECT)[None]
    elif kind == "cube":
        from .scene import box_faces

        polys = box_faces(M)
    else:
        import trimesh

        fn = sh.get("filename")
        if not fn:
            raise MitsubaSceneError(f"{key}: an {kind} shape needs a filename")
        path = fn if os.path.isabs(fn) else os.path.join(base_dir, fn)
        if not os.path.exists(path):
            raise MitsubaSceneError(f"{key}: mesh file not found: {path}")
        from .meshes import MeshError, mesh_polygons

        mesh = trimesh.load(path, force="mesh", process=False)
        try:
            polys = mesh_polygons(_apply(M, np.asarray(mesh.vertices, float)),
                                  np.asarray(mesh.faces), key)
        except MeshError as e:
            raise MitsubaSceneError(str(e)) from None
    if sh.get("flip_normals"):
        polys = polys[:, [0, 3, 2, 1]]
    return polys


def _camera(key: str, s: dict) -> dict:
    if s.get("type") != "perspective":
        raise MitsubaSceneError(f"{key}: sensor '{s.get('type')}' has no counterpart "
                                "(use 'perspective')")
    film = s.get("film", {}) or {}
    w, h = int(film.get("width", 768)), int(film.get("height", 576))
    for k in ("principal_point_offset_x", "principal_point_offset_y"):
        if float(s.get(k, 0.0)) != 0.0:
            raise MitsubaSceneError(f"{key}: {k} is not supported (centred principal point)")
    fov = float(s.get("fov", 0.0))
    if "focal_length" in s or not 0 < fov < 180:
        raise MitsubaSceneError(f"{key}: give the field of view as 'fov' in degrees (0, 180)")
    axis = s.get("fov_axis", "x")
    if axis == "smaller":
        axis = "x" if w <= h else "y"
    elif axis == "larger":
        axis = "x" if w >= h else "y"
    t = np.tan(np.radians(fov) / 2)
    if axis == "y":
        t *= w / h
    elif axis == "diagonal":
        t *= w / np.hypot(w, h)
    elif axis != "x":
        raise MitsubaSceneError(f"{key}: unknown fov_axis '{axis}'")
    M = matrix(s.get("to_world"), key)
    pos, d, up, left = M[:3, 3], M[:3, 2], M[:3, 1], M[:3, 0]
    d = d / np.linalg.norm(d)
    up = up / np.linalg.norm(up)
    if np.dot(np.cross(up, d), left) <= 0:
        raise MitsubaSceneError(f"{key}: to_world mirrors the image (its x axis must point "
                                "left: cross(up, direction))")
    return {"width": w, "height": h, "fov_deg": round(float(np.degrees(2 * np.arctan(t))), 6),
            "position": _r6(pos), "look_at": _r6(pos + d), "up": _r6(up)}


def _r6(a):
    return np.round(np.asarray(a, float), 6).tolist()


def scene_file(scene: dict, photo: str | None = None, emittance: bool = True,
               base_dir: str = ".") -> dict:
    """The Loscos scene document for a Mitsuba 3 scene dict (see the module docstring).

    photo: the photograph's file name, relative to where the scene file will be written;
    emittance: False leaves every light's emittance to be estimated; base_dir: where mesh
    file names are relative to.
    """
    if not isinstance(scene, dict) or scene.get("type") != "scene":
        raise MitsubaSceneError("expected a Mitsuba scene dict ({'type': 'scene', …})")
    defs = {k: v for k, v in scene.items() if isinstance(v, dict)
            and v.get("type") in ("diffuse", "twosided")}
    materials = {k: _albedo(v, defs, k) for k, v in defs.items()}
    polygons, lights, camera = [], [], None
    for key, v in scene.items():
        if key == "type" or key in defs:
            continue
        if not isinstance(v, dict) or "type" not in v:
            raise MitsubaSceneError(f"{key}: expected a dict with a 'type'")
        kind = v["type"]
        if kind in SHAPES:
            bsdf = v.get("bsdf")
            mat = {"material": bsdf["id"]} if isinstance(bsdf, dict) and bsdf.get("type") == "ref" \
                and bsdf.get("id") in materials else {"reflectance": _albedo(bsdf, defs, key)}
            polys = _shape_polygons(key, v, base_dir)
            em = v.get("emitter")
            if em is not None:
                if em.get("type") != "area":
                    raise MitsubaSceneError(f"{key}: emitter '{em.get('type')}' on a shape has "
                                            "no counterpart (use 'area')")
                e = (np.pi * np.asarray(_rgb(em.get("radiance", 1.0), f"{key}.emitter.radiance")))
                for q in polys:
                    item = {"name": key, **mat, "vertices": _r6(q)}
                    if emittance:
                        item["emittance"] = _r6(e)
                    lights.append(item)
            else:
                for k, q in enumerate(polys):
                    polygons.append({"name": key if len(polys) == 1 else f"{key}.{k}", **mat,
                                     "vertices": _r6(q)})
        elif kind in ("perspective", "orthographic", "thinlens", "radiancemeter",
                      "irradiancemeter"):
            if camera is not None:
                raise MitsubaSceneError(f"{key}: more than one sensor")
            camera = _camera(key, v)
        elif kind in IGNORED or key in IGNORED:
            continue
        elif kind in ("constant", "envmap", "point", "spot", "directional", "sunsky"):
            raise MitsubaSceneError(f"{key}: a '{kind}' emitter has no counterpart (Loscos "
                                    "2000 lights are area emitters on polygons)")
        else:
            raise MitsubaSceneError(f"{key}: '{kind}' has no counterpart in the scene file")
    if camera is None:
        raise MitsubaSceneError("the scene has no perspective sensor")
    doc = {"loscos_scene": 1}
    if photo:
        doc["photo"] = photo
    doc.update({"units": "metres; emittance W/m² (π × radiance)",
                "source": "converted from a Mitsuba 3 scene dict (nodes/loscos/mitsuba_scene.py)",
                "camera": camera, "materials": materials, "polygons": polygons,
                "lights": lights})
    return doc


def write_scene_file(scene: dict, path: str, photo: str | None = None, emittance: bool = True,
                     base_dir: str = ".", photo_sha256: str | None = None) -> dict:
    """scene_file(), written as YAML to ``path``; returns the document."""
    import yaml

    doc = scene_file(scene, photo, emittance, base_dir)
    if photo_sha256:
        doc["photo_sha256"] = photo_sha256
    with open(path, "w") as f:
        f.write("# generated from a Mitsuba 3 scene dict by nodes/loscos/mitsuba_scene.py\n")
        yaml.safe_dump(doc, f, allow_unicode=True, sort_keys=False, default_flow_style=None,
                       width=100)
    return doc
