"""graphs/makeup.yaml runs end to end (astronaut → FaceMesh → cosmetic map → CosmeticShade)."""
from __future__ import annotations


import numpy as np
import pytest

from conftest import ROOT, graphkit

GRAPH = ROOT / "graphs" / "makeup.yaml"


def _env():
    import os

    env = dict(os.environ)
    env.pop("GRAPHKIT_TRACEBACK", None)
    return env


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One cache for both runs: the second reuses the photo and FaceMesh results."""
    return tmp_path_factory.mktemp("huang-cache")


def _need_facemesh():
    from graphkit.registry import default_registry

    if "FaceMesh" not in default_registry().nodes:
        pytest.skip(reason="FaceMesh (plugins/graphkit-mediapipe + mediapipe 0.10.14) is not installed; `make` installs it")


def test_makeup_graph_runs(tmp_path, cache):
    _need_facemesh()
    import OpenImageIO as oiio

    out = tmp_path / "out"
    r = graphkit("run", GRAPH, "--out", out, "--cache", cache, "-q", env=_env(), timeout=300)
    assert r.returncode == 0, r.stderr
    exr, png = out / "makeup" / "made_up.exr", out / "makeup" / "contact_sheet.png"
    assert exr.is_file() and png.is_file()
    made = np.asarray(oiio.ImageBuf(str(exr)).get_pixels(oiio.FLOAT))
    from graphkit import Context
    from nodes.io.images import LoadImage

    photo = LoadImage(LoadImage.Params(path="builtin:astronaut"), Context()).compute().pixels
    assert made.shape == photo.shape == (512, 512, 3)
    assert np.isfinite(made).all() and made.min() >= 0
    changed = np.abs(made - photo).max(axis=-1) > 2e-3 * (1 + photo.max(axis=-1))
    frac = changed.mean()
    assert 0.01 < frac < 0.3, frac  # the face only; the suit, flag and shuttle are untouched
    ys, xs = np.nonzero(changed)
    assert 100 < ys.mean() < 300 and 120 < xs.mean() < 320  # around the astronaut's face
    sheet = oiio.ImageBuf(str(png))
    assert sheet.spec().width > 5 * 256 and sheet.spec().nchannels == 3


def test_makeup_graph_bad_cosmetic_via_set(tmp_path, cache):
    _need_facemesh()
    r = graphkit("run", GRAPH, "--set", "lipstick=lipstik_red", "--out", tmp_path / "o", "--cache", cache,
                 "-q", env=_env(), timeout=300)
    assert r.returncode == 2, r.stderr
    assert "cosmetics" in r.stderr and "did you mean 'lipstick_red'" in r.stderr and "Traceback" not in r.stderr
