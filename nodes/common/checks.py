"""Input checks several nodes share that no port constraint can say (graphkit.contract says the
rest on the ports): which inputs go together, spectra on one grid, what a node needs of a Light."""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Light


def _listed(names: list[str]) -> str:
    return " and ".join(names) if len(names) < 3 else ", ".join(names[:-1]) + " and " + names[-1]


def connected_together(inputs: dict, otherwise: str = "") -> bool:
    """True when every input of ``inputs`` (port → value or None) is connected, False when none
    is; else BadInput for the first unconnected one ("connect both S and K (or neither, …)")."""
    missing = [name for name, value in inputs.items() if value is None]
    if missing and len(missing) < len(inputs):
        both, neither = ("both", "neither") if len(inputs) == 2 else ("all of", "none")
        raise BadInput(missing[0], f"connect {both} {_listed(list(inputs))} (or {neither}"
                                   f"{', ' + otherwise if otherwise else ''})")
    return not missing


def inputs_or_param(inputs: dict, param: str, value, otherwise: str) -> bool:
    """Either every input of ``inputs`` is connected (True) or the param ``param`` is set
    (False), not both and not neither (BadInput; ``otherwise``: how to set it, "give a CSV path")."""
    if connected_together(inputs, f"to use '{param}'"):
        if value:
            raise BadInput(param, f"{_listed(list(inputs))} are connected: leave '{param}' empty")
        return True
    if not value:
        raise BadInput(param, f"connect {_listed(list(inputs))}, or {otherwise}")
    return False


def same_wavelengths(spectra: dict) -> None:
    """BadInput for the first Spectrum of ``spectra`` (port → Spectrum) sampled at other
    wavelengths than the first one."""
    names = list(spectra)
    wl = spectra[names[0]].wavelengths
    for name in names[1:]:
        other = spectra[name].wavelengths
        if other.shape != wl.shape or not np.array_equal(other, wl):
            raise BadInput(name, f"{_listed(names)} must be sampled at the same wavelengths")


def require_directional(light: Light, node_type: str, port: str = "light") -> None:
    """BadInput unless ``light`` is directional (the node knows no surface position per pixel)."""
    if light.kind != "directional":
        raise BadInput(port, f"{node_type} needs a directional light (no surface positions are known per pixel)")
