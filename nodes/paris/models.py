"""Pydantic models flowing between the Paris 2003 nodes."""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class PhongMaterial(BaseModel):
    """Skin parameters of the Phong model (Paris 2003 §4.2), linear RGB relative to the flash.

    ``diffuse`` is the skin colour (r, g, b) used for both ambient and diffuse terms,
    ``specular`` the grey specular intensity i_s, ``shininess`` the Phong exponent s,
    ``ambient`` the ambient light of the photo relative to the flash found after the skin fit
    (§4.1; FitSkinPhong also returns it as its output light's ambient), ``ambient_scale`` a
    multiplier Render applies to the lights' ambient terms (1 = as given), ``residual`` the L2
    Luv distance over the skin pixels (§4.2) and ``rms_luv`` the same per pixel (ΔE_uv units).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")
    diffuse: tuple[float, float, float] = (0.5, 0.35, 0.3)
    specular: float = Field(0.1, ge=0)
    shininess: float = Field(20.0, gt=0)
    ambient: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ambient_scale: float = Field(1.0, ge=0)
    residual: float = Field(0.0, ge=0)
    rms_luv: float = Field(0.0, ge=0)
    pixels: int = Field(0, ge=0, description="skin pixels used by the fit")
