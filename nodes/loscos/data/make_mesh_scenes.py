"""Write builtin:room, cornell2 and cornell3 as triangle-mesh scenes (``*_mesh.yaml``).

    .venv/bin/python nodes/loscos/data/make_mesh_scenes.py

Each scene's polygons (boxes expanded) are grouped into parts by name (``tall.3`` → ``tall``),
each parallelogram split into two triangles (a, b, c), (a, c, d).  room and cornell3 become one
OBJ each (one material per part: trimesh splits OBJ files by material); cornell2 one PLY per
part (PLY files have one part).  The scene file names the parts' materials (so the albedos are
the parallelogram scene's exactly, not the MTL's 8-bit copy), the lights as mesh parts with the
same emittances, and the same camera and photograph.  LoadScene pairs the triangles back into
parallelograms (``merge: true``, the default); tests/test_loscos_mesh.py checks the images.
"""
from __future__ import annotations

import os
import sys

import numpy as np
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", ".."))

from nodes.loscos.scene import parse_scene  # noqa: E402

SCENES = {"room": "obj", "cornell3": "obj", "cornell2": "ply"}


def parts_of(doc: dict):
    """{part: (polygons (K,4,3), material name, light entry or None)} in the file's order."""
    sc, _, _ = parse_scene(doc, base_dir=HERE)
    mat_of = {}
    for key in ("polygons", "boxes", "lights"):
        for item in doc.get(key, []) or []:
            mat_of[str(item["name"])] = item.get("material")
    lights = {str(item["name"]): item for item in doc.get("lights", []) or []}
    out = {}
    for name, v in zip(sc.names, sc.verts):
        part = name if name in mat_of else name.rsplit(".", 1)[0]
        polys, _, _ = out.setdefault(part, ([], mat_of[part], lights.get(part)))
        polys.append(v)
    return out


def triangles(polys):
    """Parallelograms (K,4,3) → vertices (4K,3), faces (2K,3): (a, b, c), (a, c, d)."""
    V = np.asarray(polys, float).reshape(-1, 3)
    k = 4 * np.arange(len(polys))[:, None]
    F = np.concatenate([k + [0, 1, 2], k + [0, 2, 3]], 1).reshape(-1, 3)
    return V, F


def write_obj(parts, mats, path):
    mtl = os.path.splitext(os.path.basename(path))[0] + ".mtl"
    lines, mlines, base = [f"mtllib {mtl}"], [], 1
    for part, (polys, mat, _) in parts.items():
        V, F = triangles(polys)
        lines += [f"o {part}", f"usemtl {part}"]
        lines += ["v " + " ".join(repr(float(x)) for x in p) for p in V]
        lines += ["f " + " ".join(str(base + i) for i in f) for f in F]
        base += len(V)
        mlines += [f"newmtl {part}", "Kd " + " ".join(repr(float(x)) for x in mats[mat])]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    with open(os.path.join(os.path.dirname(path), mtl), "w") as f:
        f.write("\n".join(mlines) + "\n")
    return [{"file": os.path.basename(path),
             "parts": {p: m for p, (_, m, _) in parts.items()}}]


def write_ply(parts, stem):
    import trimesh

    out = []
    for part, (polys, mat, _) in parts.items():
        V, F = triangles(polys)
        fn = f"{stem}_{part}.ply"
        trimesh.Trimesh(V, F, process=False).export(os.path.join(HERE, fn))
        out.append({"file": fn, "name": part, "material": mat})
    return out


def main():
    for name, fmt in SCENES.items():
        with open(os.path.join(HERE, f"{name}.yaml")) as f:
            doc = yaml.safe_load(f)
        parts = parts_of(doc)
        stem = f"{name}_mesh"
        meshes = (write_obj(parts, doc["materials"], os.path.join(HERE, stem + ".obj"))
                  if fmt == "obj" else write_ply(parts, stem))
        lights = [{k: v for k, v in item.items() if k != "vertices"} for item in doc["lights"]]
        out = {"loscos_scene": 1, "photo": doc["photo"], "photo_sha256": doc["photo_sha256"],
               "units": doc.get("units"),
               "source": f"{name}.yaml as a triangle mesh (make_mesh_scenes.py)",
               "camera": doc["camera"], "materials": doc["materials"], "meshes": meshes,
               "lights": lights}
        with open(os.path.join(HERE, stem + ".yaml"), "w") as f:
            yaml.safe_dump(out, f, sort_keys=False)
        print("wrote", stem + ".yaml", sum(len(p[0]) for p in parts.values()), "polygons")


if __name__ == "__main__":
    main()
