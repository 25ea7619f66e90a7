"""The same bytes on every CPU: the filters whose outputs are cached and compared by their bytes
give the same bytes when OpenCV's AVX2/FMA3/AVX-512 kernels are turned off
(``OPENCV_CPU_DISABLE``, read when cv2 is first imported) — what a machine without them, or with
others, would run.  OpenCV's own float filters do not: ``cv2.GaussianBlur`` on float32 (the
planted check below) changes its last bits, and CompositeFace's portraits, blended through it,
came out with other bytes on an AVX2 machine than on the AVX-512 one their digests
(tests/data/main_digests.json) were recorded on.  See nodes/common/filters.py."""
import json
import os
import subprocess
import sys
import textwrap

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OFF = "AVX2,FMA3,AVX512_SKX,AVX512_CLX,AVX512_CNL,AVX512_ICL,AVX512_KNL,AVX512_KNM"

PROBE = textwrap.dedent("""
    import hashlib, json, sys
    import numpy as np
    sys.path.insert(0, ROOT)
    from graphkit import Image, Mask
    from nodes.common.blend import SmoothFill, _blur, laplacian_blend
    from nodes.common.filters import gaussian_blur
    from nodes.huang.layer import CosmeticMap
    from nodes.io.filters import Blur
    from nodes.paris import ballfind

    def h(x):
        return hashlib.sha1(np.ascontiguousarray(x).tobytes()).hexdigest()[:16]

    def px(r):                       # a node's one output (compute returns it, or a dict of them)
        return (next(iter(r.values())) if isinstance(r, dict) else r).pixels

    rng = np.random.default_rng(7)
    img = rng.random((203, 257, 3), dtype=np.float32)
    w = (rng.random((203, 257)) > 0.6).astype(np.float32)
    out = {"gaussian_blur": h(gaussian_blur(img, 2.7)), "_blur": h(_blur(img, 13.0)),
           "smooth_fill": h(SmoothFill(w, 9.0)(img)), "laplacian": h(laplacian_blend(img, img[::-1].copy(), w, 4)),
           "Blur": h(px(Blur(Blur.Params(sigma_px=3.3)).compute(image=Image(img)))),
           "CosmeticMap": h(px(CosmeticMap(CosmeticMap.Params(thickness_mm=[0.01], feather_px=2.5))
                               .compute(regions=[Mask(w)])))}
    # a mirror ball's outline polished (ballfind._Outline) on a noisy synthetic probe
    yy, xx = np.mgrid[0:240, 0:320] + 0.5
    d = np.hypot(xx - 150.3, yy - 118.7)
    probe = np.where(d < 61.0, 0.25 + 0.1 * np.cos(xx / 7.0), 0.35) + rng.normal(0, 0.01, d.shape)
    probe[(xx - 150) ** 2 + (yy - 118) ** 2 < 9] = 1.0
    probe = np.repeat(np.clip(probe, 0, 1)[..., None], 3, 2).astype(np.float32)
    g = ballfind.stabilise(ballfind.luminance(probe))
    o = ballfind._Outline(g, None)
    out["outline"] = repr(o.polish((152.0, 117.0, 59.0)))
    fit = ballfind.find_ball(probe, None)
    out["find_ball"] = repr((fit.cx, fit.cy, fit.r, fit.confident))
    if "--planted" in sys.argv:      # OpenCV's own float blur, for the planted check
        import cv2
        out["cv2_blur"] = h(cv2.GaussianBlur(img, (0, 0), 2.7, borderType=cv2.BORDER_REFLECT))
    print(json.dumps(out))
""").replace("ROOT", repr(ROOT))


def _run(off: bool, planted: bool = False) -> dict:
    env = dict(os.environ, OPENCV_CPU_DISABLE=OFF if off else "")
    r = subprocess.run([sys.executable, "-c", PROBE] + (["--planted"] if planted else []), env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_same_bytes_with_opencv_kernels_off():
    on, off = _run(False, planted=True), _run(True, planted=True)
    import cv2

    if "AVX2" not in cv2.getCPUFeaturesLine() and "AVX512" not in cv2.getCPUFeaturesLine():
        import pytest

        pytest.fail("this CPU has neither AVX2 nor AVX-512: turning them off changes nothing here, "
                    "so the check cannot tell a CPU-dependent filter")
    planted = on.pop("cv2_blur"), off.pop("cv2_blur")
    # the check can fail: OpenCV's own float blur differs between the two
    assert planted[0] != planted[1], "cv2.GaussianBlur gave the same bytes with its AVX2/FMA3 kernels off"
    assert on == off, {k: (on[k], off[k]) for k in on if on[k] != off[k]}


def test_the_recorders_pin_holds_opencvs_ipp_to_its_avx2_kernels():
    """OpenCV's wheels carry Intel's IPP, which chooses its kernels by the CPU itself and does not
    read ``OPENCV_CPU_DISABLE``: on an Intel Xeon with AVX-512 it ran its AVX-512 kernels (k0),
    and ``cv2.resize``'s bilinear enlargement of float32 (SmoothFill, so CompositeFace's portraits)
    gave other bytes than the AVX2 ones (l9) that the digests of tests/data/main_digests.json were
    recorded with on AMD EPYCs.  The recorder's ``PINNED_ENV`` (which tests/test_same_bytes.py
    runs under) holds IPP to l9, whatever this machine would pick."""
    import pytest

    from test_same_bytes import _x86_64_v3

    if not _x86_64_v3():
        pytest.skip(reason="IPP's AVX2 kernels (l9) need an x86-64-v3 CPU; test_same_bytes skips here too")
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import record_digests, cv2; "
            "print(cv2.ipp.useIPP(), cv2.ipp.getIppVersion())")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OPENCV_", "NPY_", "OPENBLAS_"))}
    r = subprocess.run([sys.executable, "-c", code, os.path.join(ROOT, "tests", "data")], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    used, version = r.stdout.strip().split(" ", 1)
    assert used == "False" or "(l9)" in version, f"the recorder's pin left OpenCV's IPP on {version!r}"
