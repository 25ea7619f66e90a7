"""LoadCameraJson — a calibrated camera from a JSON file."""
from __future__ import annotations

from graphkit import BadInput, Camera, Field, InputFile, Node, Out

from .builtin import BuiltinFiles


class LoadCameraJson(BuiltinFiles, Node):
    """Read a :class:`graphkit.Camera` (pinhole intrinsics in pixels + 4×4 world→camera pose,
    OpenCV axes) from a JSON file with the Camera's fields (Paris 2003 §1: the calibrated
    photograph's projection)."""

    builtin_what = "camera"
    version = "1"
    outputs = {"camera": Out(Camera, "the camera")}

    class Params(Node.Params):
        path: InputFile = Field(description="JSON file with width, height, fx, fy, cx, cy, world_to_camera")

    def compute(self):
        import json

        path = self.resolve_file("path", self.params.path, self.ctx.base_dir)
        try:
            with open(path) as f:
                data = json.load(f)
            return Camera.model_validate(data)
        except (OSError, ValueError) as e:
            raise BadInput("path", f"cannot read a camera from {path}: {e}") from None
