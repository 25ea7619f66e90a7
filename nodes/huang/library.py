"""Cosmetic layer descriptions and the small example library (``data/cosmetics.json``).

A :class:`KMLayerSpec` is what flows between the Huang nodes: the S and K spectra of one
cosmetic (mm⁻¹ at wavelengths in nm, Huang 2013 §3.1/§4) plus its default thickness (mm) and
its specular parameters (§3.3: Beckmann RMS slope m, intensity ρ_s, Fresnel f0).

The library's cosmetics are **examples, not measured products**: each one's R∞ is a measured
ColorChecker spectrum from colour-science, and its thin-layer reflectance is synthetic (see
``README.md`` and ``data/build_library.py``); S and K come from KMInvert (eqs. 6–7).
"""
from __future__ import annotations

import functools
import json
from importlib.resources import files

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from graphkit import BadInput
from graphkit.suggest import closest


class KMLayerSpec(BaseModel):
    """One Kubelka–Munk cosmetic layer: S, K spectra (mm⁻¹ at nm), thickness (mm), specular."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    name: str = "layer"
    wavelengths: list[float] = Field(description="nm, uniformly spaced")
    S: list[float] = Field(description="scattering coefficient per wavelength, mm⁻¹")
    K: list[float] = Field(description="absorption coefficient per wavelength, mm⁻¹")
    thickness_mm: float = Field(0.03, ge=0, description="default thickness, mm")
    m: float = Field(0.3, gt=0, description="Beckmann RMS slope of the layer's surface (§3.3)")
    rho_s: float = Field(0.1, ge=0, description="specular intensity (§3.3, GPU Gems 3 convention)")
    f0: float = Field(0.028, ge=0, le=1, description="Fresnel reflectance at normal incidence")


@functools.lru_cache(maxsize=1)
def load_library() -> dict:
    """The parsed ``nodes/huang/data/cosmetics.json``."""
    text = (files("nodes.huang") / "data" / "cosmetics.json").read_text()
    return json.loads(text)


def cosmetic_names() -> list[str]:
    return sorted(load_library()["cosmetics"])


def get_cosmetic(name: str, port: str = "cosmetics") -> KMLayerSpec:
    """The library cosmetic ``name`` as a KMLayerSpec; BadInput(port) naming the known ones."""
    lib = load_library()
    c = lib["cosmetics"].get(name)
    if c is None:
        close = closest(name, lib["cosmetics"])
        hint = f" (did you mean '{close}'?)" if close else ""
        raise BadInput(port, f"unknown cosmetic '{name}'{hint}; known: {', '.join(cosmetic_names())}")
    sp = c.get("specular", {})
    return KMLayerSpec(name=name, wavelengths=lib["wavelengths_nm"], S=c["S_per_mm"], K=c["K_per_mm"],
                       thickness_mm=c.get("thickness_mm", 0.03), **sp)


def resolve_layers(layers, names, port_layers="layers", port_names="cosmetics") -> list[KMLayerSpec]:
    """Layers from the ``layers`` input when connected, else the library ``names`` (bottom first)."""
    if layers:
        if names:
            raise BadInput(port_names, "give either the 'layers' input or the 'cosmetics' param, not both")
        return list(layers)
    return [get_cosmetic(n, port_names) for n in names]


def layer_arrays(layers: list[KMLayerSpec], port="layers") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(wavelengths, S (n, n_λ), K (n, n_λ)) on the first layer's grid (others resampled, linear).

    Raises BadInput for negative or non-finite S/K, mismatched lengths or a non-uniform grid.
    """
    if not layers:
        wl = np.asarray(load_library()["wavelengths_nm"], np.float64)
        return wl, np.zeros((0, wl.size)), np.zeros((0, wl.size))
    wl = np.asarray(layers[0].wavelengths, np.float64)
    check_wavelengths(wl, port)
    Ss, Ks = [], []
    for i, L in enumerate(layers):
        lw = np.asarray(L.wavelengths, np.float64)
        S = np.asarray(L.S, np.float64)
        K = np.asarray(L.K, np.float64)
        if not (lw.size == S.size == K.size):
            raise BadInput(port, f"layer {i} ('{L.name}'): {lw.size} wavelengths but {S.size} S and {K.size} K values")
        for nm, v in (("S", S), ("K", K)):
            if not np.isfinite(v).all():
                raise BadInput(port, f"layer {i} ('{L.name}'): {nm} has non-finite values")
            if (v < 0).any():
                j = int(np.argmax(v < 0))
                raise BadInput(port, f"layer {i} ('{L.name}'): {nm} must be ≥ 0 mm⁻¹; {v[j]:.6g} at {lw[j]:g} nm")
        if lw.shape != wl.shape or not np.array_equal(lw, wl):
            S, K = np.interp(wl, lw, S), np.interp(wl, lw, K)
        Ss.append(S)
        Ks.append(K)
    return wl, np.stack(Ss), np.stack(Ks)


def check_wavelengths(wl: np.ndarray, port: str) -> None:
    if wl.ndim != 1 or wl.size < 2:
        raise BadInput(port, "need at least two wavelengths (nm)")
    d = np.diff(wl)
    if (d <= 0).any() or np.ptp(d) > 1e-6 * max(abs(d[0]), 1e-12):
        raise BadInput(port, "wavelengths (nm) must be increasing and uniformly spaced")
    if wl[0] < 360 - 1e-9 or wl[-1] > 830 + 1e-9:
        raise BadInput(port, f"wavelengths must lie within 360–830 nm (CIE 1931 CMFs); got {wl[0]:g}–{wl[-1]:g} nm")


def skin_spectrum(wavelengths: np.ndarray) -> np.ndarray:
    """CIE 13.3 test colour sample 13 ("human complexion", colour-science ``SDS_TCS``) at ``wavelengths``."""
    from colour.quality.datasets import SDS_TCS

    sd = SDS_TCS["CIE 1995"]["TCS13"]
    return np.interp(wavelengths, sd.wavelengths, sd.values)


@functools.lru_cache(maxsize=1)
def illuminant_names() -> tuple[str, ...]:
    """CIE illuminants that colour-science has both as an SPD and as a CIE 1931 white point."""
    import colour

    ccs = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]
    return tuple(k for k in colour.SDS_ILLUMINANTS if k in ccs)


def check_illuminant(name: str, port: str = "illuminant") -> None:
    known = illuminant_names()
    if name not in known:
        raise BadInput(port, f"unknown illuminant '{name}'; known: {', '.join(known[:24])}, …")
