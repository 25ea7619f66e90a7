"""FlashAtLens — the flash of a photo taken without a probe (a phone's flash beside its lens)."""
from __future__ import annotations

from graphkit import Camera, In, Light, Node, Out


class FlashAtLens(Node):
    """The flash when the photo has no mirror-ball probe (§4.1 measures it from one): a
    directional light along the photo camera's axis, of unit irradiance and no ambient — a phone
    flash a centimetre from its lens, seen from a face tens of centimetres away.  The run says
    so once (a notice), since every fit downstream rests on it; ProbeLight replaces it when a
    probe was photographed, MakeLight when the flash's place is known."""

    version = "1"
    inputs = {"camera": In(Camera, "the photo camera")}
    outputs = {"light": Out(Light, "the flash (world frame)")}

    def compute(self, camera: Camera):
        from .render import MakeLight

        self.ctx.notice("no probe: the flash is assumed at the lens (along the camera axis, no ambient "
                        "measured); photograph a mirror ball (ProbeLight) or place it with MakeLight "
                        "if it was elsewhere")
        return MakeLight().compute(camera)
