"""Rebuild the example cosmetics library: ``python -m nodes.huang.data.build_library``.

For each example cosmetic, R∞ is a measured ColorChecker spectrum (colour-science,
``SDS_COLOURCHECKERS["ColorChecker N Ohta"]``, 380–780 nm every 5 nm).  The thin-layer
measurement of Huang 2013 §4 (a layer of D = 0.15 mm painted over a black background, Rg = 0)
is **synthetic**: R = h · R∞ with a per-cosmetic hiding fraction h.  The CSVs in ``samples/``
hold (wavelength, R, Rg, Rinf); the KMInvert node (eqs. 6–7) turns each into S and K, written
to ``cosmetics.json``.  These are examples, not measured products.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
D_MM = 0.15  # Huang 2013 §4: depth of the shallow container

# name: (ColorChecker patch used as R∞, hiding fraction h at 0.15 mm, default thickness mm, m, rho_s)
COSMETICS = {
    "foundation_light": ("light skin", 0.95, 0.03, 0.25, 0.06),
    "foundation_dark": ("dark skin", 0.95, 0.03, 0.25, 0.06),
    "blush_rose": ("moderate red", 0.80, 0.03, 0.30, 0.05),
    "blush_orange": ("orange", 0.80, 0.03, 0.30, 0.05),
    "lipstick_red": ("red", 0.97, 0.05, 0.15, 0.35),
    "lipstick_magenta": ("magenta", 0.97, 0.05, 0.15, 0.35),
    "eyeshadow_purple": ("purple", 0.90, 0.03, 0.30, 0.05),
    "eyeshadow_blue": ("blue", 0.90, 0.03, 0.30, 0.05),
}


def main() -> None:
    import colour

    from graphkit import Context
    from nodes.huang.km import WAVELENGTHS
    from nodes.huang.layer import KMInvert

    shape = colour.SpectralShape(float(WAVELENGTHS[0]), float(WAVELENGTHS[-1]), 5.0)
    patches = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    out = {
        "description": ("Example cosmetics for the Huang 2013 nodes. R_inf: measured ColorChecker N Ohta "
                        "spectra (colour-science); thin-layer reflectance R = hiding * R_inf over black "
                        "(synthetic, D = 0.15 mm); S and K from KMInvert (Huang 2013 eqs. 6-7). "
                        "Examples, not measured products."),
        "units": {"wavelengths_nm": "nm", "S_per_mm": "1/mm", "K_per_mm": "1/mm", "thickness_mm": "mm"},
        "sample_thickness_mm": D_MM,
        "wavelengths_nm": WAVELENGTHS.tolist(),
        "cosmetics": {},
    }
    (HERE / "samples").mkdir(exist_ok=True)
    for name, (patch, h, thick, m, rho_s) in COSMETICS.items():
        rinf = patches[patch].copy().align(shape).values
        r = h * rinf
        csv_path = HERE / "samples" / f"{name}.csv"
        with open(csv_path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["wavelength", "R", "Rg", "Rinf"])
            for row in zip(WAVELENGTHS, r, np.zeros_like(r), rinf):
                w.writerow([f"{row[0]:g}", repr(float(row[1])), "0", repr(float(row[3]))])
        node = KMInvert(KMInvert.Params(path=str(csv_path), thickness_mm=D_MM, name=name), Context())
        res = node.compute()
        out["cosmetics"][name] = {
            "source": f"R_inf = ColorChecker N Ohta '{patch}'; R = {h} * R_inf at {D_MM} mm over black",
            "thickness_mm": thick,
            "specular": {"m": m, "rho_s": rho_s, "f0": 0.028},
            "S_per_mm": [round(float(v), 12) for v in res["S"].values],
            "K_per_mm": [round(float(v), 12) for v in res["K"].values],
        }
    (HERE / "cosmetics.json").write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {len(COSMETICS)} cosmetics to {HERE / 'cosmetics.json'}")


if __name__ == "__main__":
    main()
