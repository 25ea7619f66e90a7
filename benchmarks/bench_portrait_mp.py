"""A phone's or a camera's portrait through the whole face pipeline (graphs/phone_relight.yaml):
seconds, CPU and peak memory against the photo's size.

For each size, the astronaut (scikit-image) enlarged (bicubic) to the photo's height and
mirrored out to 4:3, written as an 8-bit sRGB JPEG, then ``graphkit run`` in a fresh process
(``-j 1``) with an empty cache — the cold run: every node — and again with ``--set ambient=…``
— a new light: Render, CompositeFace and the saves, over the cached preprocess.  Per size: wall
and CPU seconds, peak resident memory (the run's process), the slowest nodes; and seconds per
megapixel against the 0.26-megapixel photo of the same run (flat: the cost grows with the
pixels, no faster).

``--peer DIR``: also run each size with another checkout's code (e.g. a worktree of main), in
turn with this one's, and print the ratio — these machines are noisy, so compare only within
one invocation.

Run:  .venv/bin/python benchmarks/bench_portrait_mp.py [--sizes 512,3024] [--peer DIR] [--repeat N]
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def make_photo(height: int, path: Path) -> tuple[int, int]:
    """The astronaut enlarged to ``height`` rows and mirrored out to 4:3 → an 8-bit JPEG."""
    import cv2
    import skimage.data

    a = skimage.data.astronaut()
    big = cv2.resize(a, (height, height), interpolation=cv2.INTER_CUBIC) if height != a.shape[0] else a
    pad = (height * 4 // 3 - height) // 2
    img = cv2.copyMakeBorder(big, 0, 0, pad, pad, cv2.BORDER_REFLECT)
    cv2.imwrite(str(path), img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 92])
    return img.shape[1], img.shape[0]


def run(root: Path, graph: Path, cache: Path, out: Path, *extra: str) -> dict:
    """``graphkit run`` of ``root``'s code in a fresh process → wall and CPU seconds (system
    among them), its peak resident memory (os.wait4's rusage of that process), per-node seconds."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(root), str(root / "plugins" / "graphkit-mediapipe" / "src")]))
    cmd = [sys.executable, "-c", "import sys; from graphkit.cli import main; sys.exit(main())", "run", str(graph),
           "--cache", str(cache), "--out", str(out), "-j", "1", "-v", *extra]
    t = time.perf_counter()
    # (in the run's folder: `python -c` puts the working directory first on sys.path)
    p = subprocess.Popen(cmd, env=env, cwd=str(out.parent), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         text=True)
    text = p.stdout.read()
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        sys.exit(f"graphkit run failed ({p.returncode}):\n{text[-3000:]}")
    nodes = {m.group(1): float(m.group(2)) for m in re.finditer(r"done\s+(\S+) \(\S+\) ([\d.]+)s", text)}
    return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "sys": ru.ru_stime, "rss_gb": ru.ru_maxrss / 1e6,
            "nodes": nodes}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="512,3024", help="photo heights (4:3 wide): 512 is the astronaut as it is, "
                                                        "3024 a 12-megapixel phone photo, 4000 a 21-megapixel camera's")
    ap.add_argument("--peer", default=None, help="another checkout, run in turn with this one")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--graph", default=str(ROOT / "graphs" / "phone_relight.yaml"))
    a = ap.parse_args(argv)
    sizes = [int(s) for s in a.sizes.split(",")]
    roots = [("this", ROOT)] + ([("peer", Path(a.peer).resolve())] if a.peer else [])
    text = Path(a.graph).read_text()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-mp-") as tmp:
        tmp = Path(tmp)
        for h in sizes:
            photo = tmp / f"photo{h}.jpg"
            w, hh = make_photo(h, photo)
            graph = tmp / f"portrait{h}.yaml"
            graph.write_text(text.replace("builtin:astronaut", str(photo)))
            for rep in range(a.repeat):
                for name, root in (roots if rep % 2 == 0 else roots[::-1]):
                    cache, out = tmp / f"c{h}{name}{rep}", tmp / f"o{h}{name}{rep}"
                    cold = run(root, graph, cache, out)
                    light = run(root, graph, cache, out, "--set", "ambient=0.3")
                    rows.append({"code": name, "h": h, "mp": w * hh / 1e6, "cold": cold, "light": light})
                    slow = sorted(cold["nodes"].items(), key=lambda kv: -kv[1])[:5]
                    print(f"{name:4s} {w}×{hh} ({w * hh / 1e6:.1f} MP): cold {cold['wall']:.1f} s wall, "
                          f"{cold['cpu']:.1f} s CPU ({cold['sys']:.1f} system), peak {cold['rss_gb']:.2f} GB; "
                          f"new light {light['wall']:.1f} s wall — slowest: "
                          + ", ".join(f"{k} {v:.1f}" for k, v in slow), flush=True)
    print("\n| code | photo | MP | cold wall s | cold CPU s | peak GB | new light wall s | cold s/MP |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['code']} | {r['h'] * 4 // 3}×{r['h']} | {r['mp']:.1f} | {r['cold']['wall']:.1f} | "
              f"{r['cold']['cpu']:.1f} | {r['cold']['rss_gb']:.2f} | {r['light']['wall']:.1f} | "
              f"{r['cold']['wall'] / r['mp']:.1f} |")
    if a.peer:
        for h in sizes:
            this = [r["cold"]["wall"] for r in rows if r["h"] == h and r["code"] == "this"]
            peer = [r["cold"]["wall"] for r in rows if r["h"] == h and r["code"] == "peer"]
            print(f"height {h}: this / peer cold wall {min(this) / min(peer):.2f} (best of {len(this)} each)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
