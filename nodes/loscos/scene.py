"""LoadScene: a real scene's polygons, emitters, camera and photograph (Loscos 2000 §3).

Scene file (YAML, ``loscos_scene: 1``)::

    camera: {width: 128, height: 128, fov_deg: 39.3077, position: [0, 0, 3.9],
             look_at: [0, 0, 0], up: [0, 1, 0]}          # metres, degrees (horizontal fov)
    photo: cornell2.exr                                  # linear radiance, relative path; its
                                                         # content is part of the cache key
    photo_sha256: …                                      # optional consistency check
    materials: {white: [0.885809, 0.698859, 0.666422]}   # diffuse albedo, linear RGB
    polygons:                                            # planar parallelograms, metres,
      - {name: floor, material: white, vertices: [[...], [...], [...], [...]]}  # CCW from front
    lights:                                              # area emitters
      - {name: A, material: white, emittance: [57.8, 43.9, 21.2], vertices: [...]}  # W/m²
      - {name: B, vertices: [...]}          # no emittance (or `emittance: estimate`): from the photo
    boxes:                                               # expanded to 5 or 6 parallelograms
      - {name: tall, material: white, to_world: [[4×4]], bottom: false}  # of the cube [-1,1]³
    meshes:                                              # triangle meshes (meshes.py), relative
      - file: room.obj                                   # OBJ (parts = its materials), PLY (one
        material: white                                  # part, ``name``), glTF/GLB (its meshes);
        parts: {red_wall: red, lamp: [0.8, 0.8, 0.8]}    # albedo per part (default: ``material``,
        merge: true                                      # else the file's colour); coplanar
                                                         # triangle pairs → parallelograms
    lights:
      - {name: lamp, emittance: [10, 10, 10]}            # no vertices: the mesh part so named

Emittance is the emitted radiosity in W/m² (π × the radiance).  A light without one is
estimated from the photograph by RadiositySolve.  ``mitsuba_scene.scene_file`` writes this
format from a Mitsuba 3 scene dict.
"""
from __future__ import annotations

import os

import numpy as np

from graphkit import BadInput, Camera, Field, Image, InputFile, Node

from . import checks
from .ports import ROOM_SCENE, RoomScene

BUILTIN = {"cornell2": "cornell2.yaml", "room": "room.yaml", "cornell3": "cornell3.yaml",
           # the same scenes as triangle meshes (data/make_mesh_scenes.py)
           "room_mesh": "room_mesh.yaml", "cornell2_mesh": "cornell2_mesh.yaml",
           "cornell3_mesh": "cornell3_mesh.yaml"}
DATA = os.path.join(os.path.dirname(__file__), "data")


def camera_from_lookat(width, height, fov_deg, position, look_at, up) -> Camera:
    """Pinhole Camera (OpenCV axes) from a look-at description; fov is horizontal, degrees."""
    o = np.asarray(position, float)
    z = np.asarray(look_at, float) - o
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = -R @ o
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    return Camera(width=width, height=height, fx=f, fy=f, cx=width / 2, cy=height / 2,
                  world_to_camera=M.tolist())


def box_faces(to_world, bottom: bool = True):
    """The faces of the cube [-1,1]³ under an affine 4×4 ``to_world``, outward, as (k,4,3)."""
    M = np.asarray(to_world, float)
    faces = []
    for k in range(3):
        for sgn in (1, -1):
            a, b = (k + 1) % 3, (k + 2) % 3
            if sgn < 0:
                a, b = b, a
            n = np.zeros(3); n[k] = sgn
            ea = np.zeros(3); ea[a] = 1
            eb = np.zeros(3); eb[b] = 1
            loc = np.stack([n - ea - eb, n + ea - eb, n + ea + eb, n - ea + eb])
            w = loc @ M[:3, :3].T + M[:3, 3]
            if not bottom and k == 1 and sgn < 0:
                continue
            faces.append(w)
    return np.array(faces)


def check_polygons(verts: np.ndarray, names, port: str, rel_tol: float = 1e-6):
    """Raise BadInput for degenerate, non-planar or non-parallelogram polygons (the first in
    order): :func:`check_polygon` on the polygons a vectorised test with twice the margins
    names as suspects (a mesh of 50k triangles: 0.1 s, not 9 s of a loop over them all)."""
    v = np.asarray(verts, np.float64).reshape(-1, 4, 3)
    with np.errstate(all="ignore"):
        u, w = v[:, 1] - v[:, 0], v[:, 3] - v[:, 0]
        size = np.maximum(np.maximum(np.linalg.norm(u, axis=1), np.linalg.norm(w, axis=1)),
                          1e-300)
        c = np.cross(u, w)
        area = np.linalg.norm(c, axis=1)
        dev = np.abs(np.einsum("pc,pc->p", v[:, 2] - v[:, 0], c)) / area
        gap = np.linalg.norm(v[:, 2] - (v[:, 1] + w), axis=1)
        tri = (v[:, 2] == v[:, 3]).all(1)
        suspect = (~np.isfinite(v).all((1, 2)) | (area <= 2e-10 * size * size) | (size < 2e-9)
                   | ~(dev <= 0.5 * rel_tol * size * 10) | ((gap > 0.5e-4 * size) & ~tri))
    for p in np.flatnonzero(suspect):
        check_polygon(v[p], names[p], port, rel_tol)


def check_polygon(v: np.ndarray, name: str, port: str, rel_tol: float = 1e-6):
    """Raise BadInput if polygon v (4,3) is degenerate, non-planar or not a parallelogram."""
    if not np.all(np.isfinite(v)):
        raise BadInput(port, f"polygon '{name}' has non-finite vertices")
    u, w = v[1] - v[0], v[3] - v[0]
    size = max(np.linalg.norm(u), np.linalg.norm(w), 1e-300)
    area = np.linalg.norm(np.cross(u, w))
    if area <= 1e-10 * size * size or size < 1e-9:
        raise BadInput(port, f"polygon '{name}' is degenerate (zero area: its vertices are "
                             "collinear or repeated)")
    n = np.cross(u, w) / area
    dev = abs(np.dot(v[2] - v[0], n))
    if dev > rel_tol * size * 10:
        raise BadInput(port, f"polygon '{name}' is not planar (4th vertex is {dev:.3g} "
                             "off the plane of the other three)")
    gap = np.linalg.norm(v[2] - (v[1] + w))
    if gap > 1e-4 * size and not np.array_equal(v[2], v[3]):  # (a, b, c, c): a triangle
        raise BadInput(port, f"polygon '{name}' is not a parallelogram (v2 must equal "
                             f"v1 + v3 − v0; off by {gap:.3g}); split it into parallelograms "
                             "or triangles (3 vertices)")


def example_room(box: list | None = None) -> tuple[RoomScene, Camera, Image]:
    """The nodes' small example room (conformance cases): a 2 m room open at the front, two
    ceiling lights, optionally a box (4×4 ``to_world``) on the floor; a 40×32 px camera and a
    smooth synthetic photo.  (scene, camera, photo)."""
    sc, cam, _ = parse_scene(example_doc(box))
    return sc, cam, example_photo()


def example_photo() -> Image:
    """example_room's photo: smooth, synthetic, 40×32."""
    yy, xx = np.mgrid[0:32, 0:40] / 40.0
    return Image((0.3 + 0.4 * np.dstack([xx, yy, xx * yy])).astype(np.float32))


def example_doc(box: list | None = None) -> dict:
    """example_room as a scene document (the scene YAML's format)."""
    doc = {"loscos_scene": 1, "camera": {"width": 40, "height": 32, "fov_deg": 60,
                                         "position": [0, 0, 2.5], "look_at": [0, 0, 0]},
           "materials": {"w": [0.7, 0.6, 0.5], "r": [0.6, 0.1, 0.1], "b": [0.2, 0.3, 0.6]},
           "polygons": [{"name": "back", "material": "w", "vertices": [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1]]},
                        {"name": "floor", "material": "w", "vertices": [[-1, -1, 1], [1, -1, 1], [1, -1, -1], [-1, -1, -1]]},
                        {"name": "left", "material": "r", "vertices": [[-1, -1, 1], [-1, -1, -1], [-1, 1, -1], [-1, 1, 1]]}],
           "lights": [{"name": "A", "material": "w", "emittance": [20, 20, 16],  # facing down
                       "vertices": [[-.3, .99, -.6], [.3, .99, -.6], [.3, .99, -.2], [-.3, .99, -.2]]},
                      {"name": "B", "material": "w", "emittance": [8, 12, 16],
                       "vertices": [[.5, .99, .1], [.8, .99, .1], [.8, .99, .4], [.5, .99, .4]]}]}
    if box is not None:
        doc["boxes"] = [{"name": "box", "material": "b", "to_world": box, "bottom": False}]
    return doc


def parse_scene(doc: dict, port: str = "path",
                base_dir: str = ".") -> tuple[RoomScene, Camera, str | None]:
    """Scene YAML document → (RoomScene, Camera, photo file name or None); mesh files are
    read relative to ``base_dir``."""
    from .meshes import MeshError

    try:
        return _parse_scene(doc, port, base_dir)
    except MeshError as e:
        raise BadInput(port, str(e)) from None
    except KeyError as e:
        raise BadInput(port, f"scene file: an entry lacks the key {e}") from None
    except (TypeError, ValueError) as e:
        raise BadInput(port, f"scene file: a value has the wrong shape or type ({e})") from None


def _parse_scene(doc: dict, port: str, base_dir: str):
    if not isinstance(doc, dict) or doc.get("loscos_scene") != 1:
        raise BadInput(port, "not a scene file (expected a mapping with 'loscos_scene: 1')")
    mats = doc.get("materials", {}) or {}

    def albedo(item):
        m = item.get("material", item.get("reflectance", [0.5, 0.5, 0.5]))
        if isinstance(m, str):
            if m not in mats:
                raise BadInput(port, f"'{item.get('name')}' uses unknown material '{m}' "
                                     f"(known: {', '.join(mats)})")
            m = mats[m]
        return checks.reflectance(m, port, f"'{item.get('name')}'")

    names, verts, refl, emit, light, given = [], [], [], [], [], []

    def add(name, v, rho, e=np.zeros(3), lname="", known=True):
        if v.shape == (3, 3):  # a triangle (a, b, c) → (a, b, c, c)
            v = v[[0, 1, 2, 2]]
        names.append(name); verts.append(v); refl.append(rho); emit.append(e)
        light.append(lname); given.append(known)

    for item in doc.get("polygons", []) or []:
        add(str(item["name"]), np.asarray(item["vertices"], float), albedo(item))
    for item in doc.get("boxes", []) or []:
        for k, f in enumerate(box_faces(item["to_world"], item.get("bottom", True))):
            add(f"{item['name']}.{k}", f, albedo(item))
    parts = mesh_parts_of(doc, port, base_dir, mats, albedo)
    lights = doc.get("lights", []) or []
    if parts and not lights:
        raise BadInput(port, "the scene has no light: name the mesh parts that emit under "
                             f"'lights:' (mesh parts: {', '.join(p[0] for p in parts)})")
    light_parts = {str(item.get("name")) for item in lights if "vertices" not in item}
    for pname, polys, rho in parts:
        if pname not in light_parts:
            for k, f in enumerate(polys):
                add(f"{pname}.{k}", f, rho)
    by_name = {p[0]: p for p in parts}
    for item in lights:
        e, known = light_emittance_of(item, port, by_name)
        lname = str(item["name"])
        if "vertices" in item:
            add(lname, np.asarray(item["vertices"], float), albedo(item), e, lname, known)
            continue
        _, polys, rho = by_name[lname]
        rho = albedo(item) if ("material" in item or "reflectance" in item) else rho
        for k, f in enumerate(polys):
            add(f"{lname}.{k}" if len(polys) > 1 else lname, f, rho, e, lname, known)
    for n, v in zip(names, verts):
        if v.shape != (4, 3):
            raise BadInput(port, f"polygon '{n}' needs 4 (or 3) vertices of 3 coordinates, got "
                                 f"{v.shape}")
    if not names:
        raise BadInput(port, "the scene has no polygons")
    verts = np.array(verts)
    check_polygons(verts, names, port)
    check_emitters(verts, np.array(emit), names, port)
    c = doc.get("camera")
    if not c:
        raise BadInput(port, "the scene has no camera")
    cam = camera_from_lookat(int(c["width"]), int(c["height"]), float(c["fov_deg"]),
                             c["position"], c["look_at"], c.get("up", [0, 1, 0]))
    return (RoomScene(names, verts, np.array(refl), np.array(emit), light,
                      emit_given=np.array(given, bool)), cam, doc.get("photo"))


def mesh_files(doc: dict, base_dir: str) -> list[str]:
    """The paths of the mesh files a scene document names (relative to ``base_dir``)."""
    items = doc.get("meshes", []) if isinstance(doc, dict) else []
    return [os.path.join(base_dir, str(m["file"])) for m in items or []
            if isinstance(m, dict) and "file" in m]


def mesh_parts_of(doc: dict, port: str, base_dir: str, mats: dict, albedo):
    """[(part name, polygons (K,4,3), albedo (3,))] of the scene's ``meshes`` entries."""
    from .meshes import mesh_parts, mesh_polygons

    out = []
    for item, path in zip(doc.get("meshes", []) or [], mesh_files(doc, base_dir)):
        if not os.path.exists(path):
            raise BadInput(port, f"mesh file not found: {path}")
        chosen = item.get("parts", {}) or {}
        for pname, V, F, file_rho in mesh_parts(path, item.get("name")):
            if pname in chosen:
                rho = albedo({"name": pname, "material": chosen[pname]})
            elif "material" in item or file_rho is None:
                if "material" not in item:
                    raise BadInput(port, f"mesh {item['file']}: part '{pname}' has no colour in "
                                         "the file: give it a material (parts: or material:)")
                rho = albedo({"name": pname, "material": item["material"]})
            else:
                rho = checks.reflectance(file_rho, port, f"mesh part '{pname}'")
            where = f"mesh {item['file']}, part '{pname}'"
            out.append((pname, mesh_polygons(V, F, where, bool(item.get("merge", True))), rho))
        unknown = set(chosen) - {p[0] for p in out}
        if unknown:
            raise BadInput(port, f"mesh {item['file']} has no part " + ", ".join(
                f"'{u}'" for u in sorted(unknown)) + f" (its parts: {', '.join(p[0] for p in out)})")
    return out


def light_emittance_of(item: dict, port: str, parts: dict | None = None) -> tuple[np.ndarray, bool]:
    """A light's emittance (W/m²) and whether the file gives it (no value / "estimate": no).

    A light without vertices is the mesh part of its name (``parts``: name → part)."""
    name = item.get("name")
    if "name" not in item or ("vertices" not in item and not parts):
        raise BadInput(port, f"a light needs a name and vertices (got keys {sorted(item)})")
    if "vertices" not in item and str(name) not in parts:
        raise BadInput(port, f"light '{name}' has no vertices and no mesh part of that name "
                             f"(mesh parts: {', '.join(parts)})")
    v = item.get("emittance")
    if v is None or (isinstance(v, str) and v == "estimate"):
        return np.zeros(3), False
    return checks.emittance(v, port, f"light '{name}'", " or 'estimate'"), True


def check_emitters(verts, emit, names, port):
    from .geometry import frame

    area = frame(verts)[4]
    for n, a, e in zip(names, area, emit):
        if np.any(e > 0) and a <= 1e-12:
            raise BadInput(port, f"emitter '{n}' has zero area")



def check_camera_sees(scene: RoomScene, cam: Camera, port: str):
    """BadInput unless some polygon is in front of the camera and inside its frame (every 4th
    pixel's ray, through Embree where it is installed: textures.first_hit answers as the
    reference but for near-ties in depth)."""
    import contextlib

    from nodes.common import rays

    from .textures import pixel_map

    with rays.using("embree") if rays.embree_missing() is None else contextlib.nullcontext():
        pp, _ = pixel_map(scene.verts, cam, step=4)
    if not (pp >= 0).any():
        raise BadInput(port, "the camera sees no polygon of the scene")


class LoadScene(Node):
    """Load a real scene: polygons, reflectances, area emitters, camera, photograph (§3).

    ``path`` is a scene YAML (format in the module docstring) or ``builtin:cornell2`` — a
    Cornell box with Mitsuba's ``cornell_box()`` geometry and colours plus a second area
    light, photographed (rendered) by Mitsuba 3 (nodes/loscos/data/make_cornell2.py) —,
    ``builtin:room`` (a room with a table, a window-like light and a lamp) or
    ``builtin:cornell3`` (two other lights), both from Mitsuba scene dicts (make_scenes.py);
    ``builtin:room_mesh``, ``cornell2_mesh``, ``cornell3_mesh``: the same as mesh files.
    A light may leave its emittance out (RadiositySolve estimates it from the photograph).
    Units: metres, W/m² (emittance = π × radiance), photograph in linear radiance.
    """

    version = "2"
    outputs = {"scene": ROOM_SCENE, "camera": Camera, "photo": Image}

    class Params(Node.Params):
        path: InputFile = Field(description="scene YAML, relative to the graph, or builtin:NAME")

    @classmethod
    def resolve_file(cls, param, value, base_dir):
        if value.startswith("builtin:"):
            from nodes.io.builtin import builtin_path

            return builtin_path(value, param, BUILTIN, package=__package__, folder="data", what="scene")
        return super().resolve_file(param, value, base_dir)

    @classmethod
    def referenced_files(cls, param, path):
        """The photograph the scene file names: its content is part of the cache key."""
        import yaml

        try:
            with open(path) as f:
                doc = yaml.safe_load(f)
        except (OSError, yaml.YAMLError):
            return {}  # compute reports the problem with the scene file itself
        out = {f"mesh{k}": m for k, m in enumerate(mesh_files(doc, os.path.dirname(path)))}
        if isinstance(doc, dict) and isinstance(doc.get("photo"), str):
            out["photo"] = os.path.join(os.path.dirname(path), doc["photo"])
        return out

    def compute(self):
        import yaml

        from nodes.io.images import read_image

        path = self.resolve_file("path", self.params.path, self.ctx.base_dir)
        if not os.path.exists(path):
            raise BadInput("path", f"scene file not found: {path}")
        with open(path) as f:
            try:
                doc = yaml.safe_load(f)
            except yaml.YAMLError as e:
                raise BadInput("path", f"{path}: not valid YAML: {e}") from None
        scene, cam, photo = parse_scene(doc, base_dir=os.path.dirname(path))
        if not photo:
            unknown = [s for s, g in zip(scene.light_names, scene.light_given()) if not g]
            if unknown:
                raise BadInput("path", "light " + ", ".join(f"'{s}'" for s in unknown)
                               + " gives no emittance and the scene file names no photo to "
                                 "estimate it from")
            raise BadInput("path", "the scene file names no photo")
        photo_path = os.path.join(os.path.dirname(path), photo)
        if not os.path.exists(photo_path):
            raise BadInput("path", f"photo not found: {photo_path}")
        if doc.get("photo_sha256"):
            import hashlib

            with open(photo_path, "rb") as f:
                if hashlib.sha256(f.read()).hexdigest() != doc["photo_sha256"]:
                    raise BadInput("path", f"{photo_path} does not match photo_sha256 in {path}")
        px, _ = read_image(photo_path)
        px = px[:, :, :3]
        if px.shape[:2] != (cam.height, cam.width):
            raise BadInput("path", f"photo is {px.shape[1]}×{px.shape[0]} but the camera is "
                                   f"{cam.width}×{cam.height}")
        check_camera_sees(scene, cam, "path")
        return {"scene": scene, "camera": cam, "photo": Image(px)}
