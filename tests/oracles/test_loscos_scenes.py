"""Loscos 2000 on builtin:cornell3 — a check scene, nothing was tuned on it (make_scenes.py) —
with every light's emittance estimated from the photograph, against Mitsuba 3 references
rendered from the scene dict (nodes/loscos/data/cornell3_*.exr, 512 spp).

Measured numbers are printed (run with -s); benchmarks/loscos_scenes.py gives the full table
(given vs estimated, builtin:room — not a Cornell box, too slow for the suite — and cornell3).
"""
import os

import numpy as np
import pytest

from graphkit import Context
from nodes.common.color import linear_to_srgb
from nodes.io.images import read_image
from nodes.loscos.radiosity import RadiositySolve, TextureRefine
from nodes.loscos.relight import Relight, Unocclude
from nodes.loscos.scene import DATA, LoadScene
from nodes.loscos.textures import ProjectTextures

# graphs/room_relight.yaml's settings
RADIOSITY = dict(eps_bf=0.3, eps_bfv=0.03, min_area=0.002, max_level=6)
REFINE = dict(max_level=6, min_area=0.0005, max_rounds=2)
pytestmark = pytest.mark.xdist_group("loscos-cornell3")  # one worker builds the pipeline once
VIRTUAL = {"name": "V", "center": [-0.45, 0.9, -0.5], "size": [0.3, 0.3], "normal": [0, -1, 0],
           "emittance": [36.0, 36.0, 40.0]}  # make_scenes.CASES["cornell3"]


def run(cls, params=None, **kw):
    return cls(cls.Params(**(params or {})), Context()).compute(**kw)


def psnr(a, b, mask=None):
    """PSNR in dB of sRGB-encoded images clipped to [0, 1] (display values)."""
    enc = lambda x: np.clip(linear_to_srgb(np.clip(x, 0, None)), 0, 1)  # noqa: E731
    d = (enc(a) - enc(b)) ** 2
    return 10 * np.log10(1.0 / np.mean(d if mask is None else d[mask]))


@pytest.fixture(scope="session")  # kept while xdist interleaves other modules
def c3():
    s = run(LoadScene, {"path": "builtin:cornell3"})
    pr = run(ProjectTextures, {}, scene=s["scene"], camera=s["camera"], photo=s["photo"])
    out = run(RadiositySolve, dict(RADIOSITY, emittance="estimate"), scene=s["scene"],
              projection=pr)
    sol = run(TextureRefine, REFINE, scene=s["scene"], solution=out["solution"], projection=pr)
    un = run(Unocclude, {}, solution=sol, projection=pr, photo=s["photo"])["unoccluded"]
    return dict(s, projection=pr, solution=sol, unoccluded=un, lights=out["lights"])


def test_cornell3_emittances_estimated(c3):
    sc, sol = c3["scene"], c3["solution"]
    assert all(v["source"] == "estimated" for v in c3["lights"]["lights"].values())
    for k, name in enumerate(sol.lights):
        true = sc.emittance[sc.light.index(name)]  # the file's values, not used by the solve
        err = sol.emit[k] / true - 1
        print(f"light {name}: estimated {np.round(sol.emit[k], 2).tolist()} W/m², true "
              f"{true.tolist()}, error {np.round(100 * err, 2).tolist()} %")
        assert np.abs(err).max() < 0.05


@pytest.mark.parametrize("case,params,goal", [
    ("A_off", {"light_scale": {"warm": 0.0}}, 30.0),
    ("B_x2", {"light_scale": {"cyan": 2.0}}, 33.0),
    ("virtual", {"virtual_lights": [VIRTUAL], "eps_bf": 0.3, "eps_bfv": 0.03}, 30.0),
])
def test_cornell3_relit_with_estimated_emittances(c3, case, params, goal):
    ref, _ = read_image(os.path.join(DATA, f"cornell3_{case}.exr"))
    img = run(Relight, params, solution=c3["solution"], unoccluded=c3["unoccluded"],
              projection=c3["projection"], photo=c3["photo"], camera=c3["camera"]).pixels
    pr = c3["projection"]
    inside = (pr.pix_poly >= 0).reshape(-1)
    inside[pr.sub_pix[(pr.sub_poly >= 0).any(1)]] = True  # pixels that see a polygon at all
    inside = inside.reshape(pr.pix_poly.shape)
    p_in, p_all = psnr(img, ref[..., :3], inside), psnr(img, ref[..., :3])
    p_photo = psnr(c3["photo"].pixels, ref[..., :3])
    print(f"cornell3 {case}: PSNR inside {p_in:.1f} dB, whole image {p_all:.1f} dB (unchanged "
          f"photo {p_photo:.1f} dB)")
    assert p_in >= goal and p_all >= goal
    assert p_all > p_photo
