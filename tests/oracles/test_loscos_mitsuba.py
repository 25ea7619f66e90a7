"""Loscos 2000 nodes on builtin:cornell2 against Mitsuba 3 (scalar_rgb) renders.

Measured numbers are printed (run with -s); see nodes/loscos/README.md.
"""
import numpy as np
import pytest

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is the outside reference for these tests")
pytestmark = pytest.mark.xdist_group("loscos-cornell2")  # one worker builds the pipeline once

from graphkit import Context  # noqa: E402
from nodes.common.color import linear_to_srgb  # noqa: E402
from nodes.loscos import mitsuba_ref as MR  # noqa: E402
from nodes.loscos.ports import RoomScene  # noqa: E402
from nodes.loscos.radiosity import RadiositySolve, TextureRefine, finish_solution  # noqa: E402
from nodes.loscos.relight import Relight, Unocclude  # noqa: E402
from nodes.loscos.scene import LoadScene  # noqa: E402
from nodes.loscos.textures import ProjectTextures  # noqa: E402

LUM = np.array([0.2126, 0.7152, 0.0722])
# rays=8 (64 visibility rays per link, not the default 16): the per-tile check below is about the
# method's bias, and with 16 rays the ray noise alone moved the back wall's worst tile by
# 0.034-0.049 over seeds 0-3 on the same code (the limit is 0.05), so a change that only drew
# its rays in another order passed or failed by luck; with 64: 0.029-0.036 over seeds.
FAST = dict(eps_bf=0.3, eps_bfv=0.03, min_area=0.002, max_level=6, rays=8)
VLIGHT = {"name": "V", "center": [0.55, 0.9, -0.45], "size": [0.3, 0.3], "normal": [0, -1, 0],
          "emittance": [40.0, 36.0, 28.0]}


def run(node_cls, params=None, **inputs):
    n = node_cls(node_cls.Params(**(params or {})), Context())
    return n.compute(**inputs)


@pytest.fixture(scope="session")  # kept while xdist interleaves other modules
def pipe():
    s = run(LoadScene, {"path": "builtin:cornell2"})
    pr = run(ProjectTextures, {}, scene=s["scene"], camera=s["camera"], photo=s["photo"])
    sol = run(RadiositySolve, FAST, scene=s["scene"], projection=pr)["solution"]
    ref = run(TextureRefine, {"max_level": 6, "min_area": 5e-4, "max_rounds": 2},
              scene=s["scene"], solution=sol, projection=pr)
    un = run(Unocclude, {}, solution=ref, projection=pr, photo=s["photo"])
    return dict(s, projection=pr, solution=ref, unoccluded=un["unoccluded"])


def mitsuba_render(scene: RoomScene, cam_doc, spp=64, **kw):
    import yaml

    from nodes.loscos.scene import DATA

    c = yaml.safe_load(open(f"{DATA}/cornell2.yaml"))["camera"]
    return MR.render_photo(scene, (c["position"], c["look_at"], c["up"]), c["fov_deg"],
                           c["width"], c["height"], spp, seed=11, **kw)


def psnr(a, b):
    """PSNR in dB of sRGB-encoded images clipped to [0, 1] (display values)."""
    enc = lambda x: np.clip(linear_to_srgb(np.clip(x, 0, None)), 0, 1)  # noqa: E731
    return 10 * np.log10(1.0 / np.mean((enc(a) - enc(b)) ** 2))


def floor_tiles_under_boxes(sc: RoomScene, n: int) -> np.ndarray:
    """(n²,) whether the centre of each floor tile (polygon 0, s-major) lies under a box top."""
    from nodes.loscos.geometry import dual_basis, frame

    o, u, w, _, _ = frame(sc.verts[0][None])
    st = (np.arange(n) + 0.5) / n
    S, T = np.meshgrid(st, st, indexing="ij")
    c = o + S.reshape(-1, 1) * u + T.reshape(-1, 1) * w  # (n², 3) tile centres
    out = np.zeros(n * n, bool)
    for q in range(5, len(sc.verts)):
        qo, qu, qv, qn, _ = frame(sc.verts[q][None])
        if sc.light[q] or qn[0, 1] < 0.99:  # box tops only (normal +y)
            continue
        du, dv = dual_basis(qu, qv)
        d = (c - qo) * [1, 0, 1]  # compare in the floor plane (x, z)
        a, b = d @ (du[0] * [1, 0, 1]), d @ (dv[0] * [1, 0, 1])
        out |= (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    return out


def test_irradiance_per_patch_vs_mitsuba(pipe):
    """Leaf irradiance averaged over 4×4 tiles of the five walls vs Mitsuba (see
    mitsuba_ref.tile_irradiance for why radiance/ρ replaces the irradiancemeter)."""
    sc = pipe["scene"]
    sol = finish_solution(sc, pipe["solution"].hierarchy(), pipe["projection"], "scene", 0.5, 0,
                          1e-7, {})
    H = sol.H()
    h = sol.hierarchy()
    pos = np.full(h.n_elems, -1)
    pos[sol.leaves] = np.arange(len(sol.leaves))
    grid = h.leaf_grid()[..., 0]  # (a parallelogram's two halves of a cell hold the same leaf)
    G = grid.shape[1]
    walls = [0, 1, 2, 3, 4]
    irr = MR.tile_irradiance(sc, walls, 4, res=32, spp=1024)  # ~1 % noise per tile
    under = floor_tiles_under_boxes(sc, 4)
    worst_tile, worst_wall, errs = 0.0, 0.0, []
    for p in walls:
        tile = H[pos[grid[p]]].reshape(4, G // 4, 4, G // 4, 3).mean((1, 3)).reshape(16, 3) @ LUM
        ref = np.array([irr[(p, k)] for k in range(16)]) @ LUM
        # a floor tile whose centre a box stands on is mostly unlit floor plus a strip along
        # the box's contact edge: reported apart, not asserted
        lit = ~under if p == 0 else np.ones(16, bool)
        e = tile / ref - 1
        ew = tile.sum() / ref.sum() - 1
        dark = "  ".join(f"{k}: {e[k]:+.3f} (E {ref[k] / ref.max():.2f} of max)"
                         for k in np.flatnonzero(~lit))
        print(f"{sc.names[p]:10s} wall {ew:+.3f}  max tile {np.abs(e[lit]).max():.3f}"
              + (f"  dark tiles {dark}" if dark else ""))
        worst_tile = max(worst_tile, np.abs(e[lit]).max())
        errs += list(np.abs(e[lit]))
        worst_wall = max(worst_wall, abs(ew))
    within = np.mean(np.array(errs) < 0.05)
    print(f"tiles within 5 %: {within:.2f}; worst wall {worst_wall:.3f}; worst tile {worst_tile:.3f}")
    # Issue 4: within 5 % per patch (every lit tile) and 2 % per wall
    assert worst_wall < 0.02
    assert worst_tile < 0.05


def light_rim(pix_poly, light_polys, width=2):
    """Pixels within ``width`` px of a light's pixels, not on it (the rim where photo pixels mix
    the emitter with the ceiling)."""
    from scipy.ndimage import binary_dilation

    on = np.isin(pix_poly, light_polys)
    return binary_dilation(on, iterations=width) & ~on, on


def test_light_a_off_vs_mitsuba(pipe):
    sc = pipe["scene"]
    fixture = sc.reflectance[sc.light.index("A")]  # the scene's fixture, as Mitsuba renders it
    ref = mitsuba_render(sc, None, spp=512, emit_scale={"A": 0.0})
    out = run(Relight, {"light_scale": {"A": 0.0}, "fixture_reflectance": tuple(fixture)},
              solution=pipe["solution"], unoccluded=pipe["unoccluded"],
              projection=pipe["projection"], photo=pipe["photo"])
    photo = pipe["photo"].pixels
    p_out, p_photo = psnr(out.pixels, ref), psnr(photo, ref)
    # A's shadows: pixels where A's contribution (photo − B-only render) is < 40 % of its
    # 90th percentile on the same polygon; "lit" = the other pixels of those polygons.
    pp = pipe["projection"].pix_poly
    cA = (photo - ref) @ LUM
    lum_ref = ref @ LUM
    shadow = np.zeros(pp.shape, bool)
    lit = np.zeros(pp.shape, bool)
    for p in np.unique(pp[pp >= 0]):
        m = (pp == p) & (lum_ref > 0.02)
        if sc.light[p] or m.sum() < 50:
            continue
        sh = m & (cA < 0.4 * np.percentile(cA[m], 90))
        if sh.sum() >= 10:
            shadow |= sh
            lit |= m & ~sh
    r_out = (out.pixels @ LUM) / np.maximum(lum_ref, 1e-6)
    r_photo = (photo @ LUM) / np.maximum(lum_ref, 1e-6)
    # the A-shadow contrast that survives relighting, as a fraction of its contrast in the
    # photograph (0: gone; 1: as strong as in the photo)
    remain = (r_out[shadow].mean() - r_out[lit].mean()) / (r_photo[shadow].mean()
                                                           - r_photo[lit].mean())
    # the ceiling pixels within 2 px of a light (photo pixels there mix emitter and ceiling)
    # against the rest of the ceiling: mean |error| of the display (sRGB) values
    enc = lambda x: np.clip(linear_to_srgb(np.clip(x, 0, None)), 0, 1)  # noqa: E731
    err = np.abs(enc(out.pixels) - enc(ref)).mean(2)
    rim, _ = light_rim(pp, [p for p, n in enumerate(sc.light) if n])
    ceiling = pp == sc.names.index("ceiling")
    e_rim, e_rest = err[rim & ceiling].mean(), err[ceiling & ~rim].mean()
    print(f"A off: PSNR {p_out:.1f} dB (photo vs ref {p_photo:.1f} dB); A-shadow pixels "
          f"{shadow.sum()}: contrast remaining {remain:+.3f} of the photo's; light rim "
          f"{(rim & ceiling).sum()} px: mean error {e_rim:.4f}, rest of the ceiling {e_rest:.4f}"
          f" ({e_rim / e_rest:.2f}×)")
    assert abs(remain) < 0.15
    assert p_out >= 38.0
    assert e_rim <= 2 * e_rest


def test_virtual_light_vs_mitsuba(pipe):
    from nodes.loscos.relight import quad_from

    sc = pipe["scene"]
    q = quad_from(VLIGHT["center"], VLIGHT["size"], VLIGHT["normal"])
    sc2 = RoomScene(sc.names + ["V"], np.concatenate([sc.verts, q[None]]),
                    np.concatenate([sc.reflectance, np.zeros((1, 3))]),
                    np.concatenate([sc.emittance, [VLIGHT["emittance"]]]), sc.light + ["V"])
    ref = mitsuba_render(sc2, None, spp=512)
    out = run(Relight, {"virtual_lights": [VLIGHT], "eps_bf": 0.3, "eps_bfv": 0.03},
              solution=pipe["solution"], unoccluded=pipe["unoccluded"],
              projection=pipe["projection"], photo=pipe["photo"], camera=pipe["camera"])
    p_out, p_photo = psnr(out.pixels, ref), psnr(pipe["photo"].pixels, ref)
    print(f"virtual light: PSNR {p_out:.1f} dB (unchanged photo vs ref {p_photo:.1f} dB)")
    assert p_out >= 30.0
    assert p_out > p_photo
