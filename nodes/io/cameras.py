"""LoadCameraJson — a calibrated camera from a JSON file."""
from __future__ import annotations

from graphkit import BadInput, Camera, Field, InputFile, Node, Out

from .builtin import BuiltinFiles

#: keys people write for camera fields, and what to write instead
_HINTS = {
    "type": "projection", "model": "projection", "camera_type": "projection",
    "scale": "pixels_per_m", "ortho_scale": "pixels_per_m", "pixels_per_meter": "pixels_per_m",
    "pixels_per_metre": "pixels_per_m", "ppm": "pixels_per_m",
    "focal": "fx and fy", "f": "fx and fy", "focal_length": "fx and fy", "K": "fx, fy, cx, cy",
    "intrinsics": "fx, fy, cx, cy", "pose": "world_to_camera", "extrinsics": "world_to_camera",
    "view": "world_to_camera", "w": "width", "h": "height", "units": "metres_per_unit",
    "unit": "metres_per_unit", "meters_per_unit": "metres_per_unit",
}


class LoadCameraJson(BuiltinFiles, Node):
    """Read a :class:`graphkit.Camera` from a JSON object with the Camera's fields (Paris 2003 §1:
    the calibrated photograph's projection).

    Perspective: ``{"width", "height", "fx", "fy", "cx", "cy", "world_to_camera"}`` (pixels,
    OpenCV axes); orthographic: ``"projection": "orthographic"`` with ``pixels_per_m`` instead of
    fx/fy.  ``metres_per_unit`` (default 1) gives the world's length unit (0.001: meshes in mm).
    The pose may be given as ``camera_to_world`` instead (it is inverted).  Any problem is one
    message naming the file and the field.
    """

    builtin_what = "camera"
    version = "2"
    outputs = {"camera": Out(Camera, "the camera")}

    class Params(Node.Params):
        path: InputFile = Field(description="JSON file with the Camera fields (width, height, "
                                            "projection, fx, fy | pixels_per_m, cx, cy, world_to_camera, "
                                            "metres_per_unit)")

    def compute(self):
        import json

        path = self.resolve_file("path", self.params.path, self.ctx.base_dir)
        try:
            with open(path) as f:
                data = json.load(f)
        except OSError as e:
            raise BadInput("path", f"cannot read {path}: {e.strerror or e}") from None
        except ValueError as e:
            raise BadInput("path", f"{path} is not valid JSON: {e}") from None
        return camera_from_dict(data, str(path))


def camera_from_dict(data, where: str) -> Camera:
    """A Camera from a JSON-like dict; BadInput("path", one message naming ``where`` and the
    field) on any problem."""
    import difflib

    import numpy as np
    from pydantic import ValidationError

    if not isinstance(data, dict):
        raise BadInput("path", f"{where}: a camera is a JSON object of fields, got {type(data).__name__}")
    data = dict(data)
    if "camera_to_world" in data:
        if "world_to_camera" in data:
            raise BadInput("path", f"{where}: give world_to_camera or camera_to_world, not both")
        try:
            M = np.asarray(data.pop("camera_to_world"), dtype=np.float64)
            data["world_to_camera"] = np.linalg.inv(M).tolist()
        except (ValueError, TypeError, np.linalg.LinAlgError) as e:
            raise BadInput("path", f"{where}: field 'camera_to_world': not an invertible 4×4 matrix ({e})") from None
    fields = list(Camera.model_fields)
    for key in data:
        if key not in fields:
            hint = _HINTS.get(key) or ", ".join(difflib.get_close_matches(key, fields, n=2, cutoff=0.6))
            msg = f"{where}: unknown field '{key}'"
            if hint:
                msg += f"; did you mean {hint}?"
            raise BadInput("path", msg + "  " + _FORMS)
    try:
        return Camera.model_validate(data)
    except ValidationError as e:
        errs = e.errors()
        first = errs[0]
        loc = ".".join(str(x) for x in first["loc"]) or "(the camera)"
        msg = first["msg"].removeprefix("Value error, ")
        more = f" (and {len(errs) - 1} more problem{'s' if len(errs) > 2 else ''})" if len(errs) > 1 else ""
        if first["type"] == "missing":
            msg = "missing"
        raise BadInput("path", f"{where}: field '{loc}': {msg}{more}.  {_FORMS}") from None


_FORMS = ("A camera file holds width, height, cx, cy, world_to_camera and either fx, fy "
          "(perspective, pixels) or \"projection\": \"orthographic\" with pixels_per_m.")
