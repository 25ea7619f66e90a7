"""One cache, several Unix users (issue 10): a group-writable cache works for a second user of
the group (even an all-cached run), and a read-only, fully populated cache serves hits for
`run`, `cache ls`, `cache verify` and `explain`.  Both fail on the store before issue 10.

root ignores file permissions, so the commands run as real second users (created here with
useradd when missing: gkuser1, gkuser2 in group gkshare) through setpriv.  They keep one
capability, CAP_DAC_READ_SEARCH, only so that they can read the interpreter under /root; it
grants reads and folder searches, never writes, so every write below is checked as for any user.
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import engine_env

GROUP, USERS = "gkshare", ("gkuser1", "gkuser2")
G = """\
graphkit: 1
name: shared
params: {v: 2.0}
nodes:
  a: {type: Const, params: {value: "${params.v}", size: 1000}}
  b: {type: Add, inputs: {a: a.out}, params: {offset: 1}}
outputs: {b: b.out}
"""


@pytest.fixture(scope="module")
def users():
    if os.geteuid() != 0:
        import pwd

        try:
            [pwd.getpwnam(u) for u in USERS]
        except KeyError:
            pass
        pytest.skip(reason="needs root to run commands as a second Unix user (setpriv); run as root "
                           "(make test does) or create gkuser1/gkuser2 in group gkshare")
    if shutil.which("setpriv") is None:
        pytest.skip(reason="needs setpriv (util-linux) to run commands as another user")
    if subprocess.run(["getent", "group", GROUP], capture_output=True).returncode != 0:
        subprocess.run(["groupadd", GROUP], check=True, capture_output=True)
    for u in USERS:
        if subprocess.run(["id", u], capture_output=True).returncode != 0:
            subprocess.run(["useradd", "-M", "-N", "-g", GROUP, "-s", "/usr/sbin/nologin", u],
                           check=True, capture_output=True)
    import grp
    import pwd

    return {u: pwd.getpwnam(u).pw_uid for u in USERS}, grp.getgrnam(GROUP).gr_gid


def as_user(user, *args, cwd="/"):
    env = engine_env({"HOME": "/tmp"})
    cmd = ["setpriv", f"--reuid={user}", f"--regid={GROUP}", "--init-groups",
           "--inh-caps=+dac_read_search", "--ambient-caps=+dac_read_search",
           sys.executable, "-m", "graphkit", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd, timeout=120,
                          preexec_fn=lambda: os.umask(0o022))


def user_dir(path: Path, uid: int, gid: int, mode=0o755) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    os.chown(path, uid, gid)
    os.chmod(path, mode)
    return path


def test_second_user_of_a_group_writable_cache(tmp_path, write, users):
    uids, gid = users
    os.chmod(tmp_path, 0o755)
    g = write("g.yaml", G)
    cache = tmp_path / "cache"
    cache.mkdir()
    os.chown(cache, 0, gid)
    os.chmod(cache, 0o2775)  # what an admin does for a team cache
    o1 = user_dir(tmp_path / "o1", uids["gkuser1"], gid)
    o2 = user_dir(tmp_path / "o2", uids["gkuser2"], gid)
    r = as_user("gkuser1", "run", g, "--cache", cache, "--out", o1)
    assert r.returncode == 0, r.stderr
    for name in ("store.lock", "keys.lock"):
        p = cache / name
        if p.exists():
            assert p.stat().st_mode & 0o060 == 0o060, (name, oct(p.stat().st_mode))
    r = as_user("gkuser2", "run", g, "--cache", cache, "--out", o2)  # all cached
    assert r.returncode == 0 and "0 computed, 2 cached" in r.stderr, r.stderr
    r = as_user("gkuser2", "run", g, "--cache", cache, "--out", o2, "--set", "v=5")  # new entries
    assert r.returncode == 0 and "2 computed" in r.stderr, r.stderr
    np.testing.assert_array_equal(np.load(o2 / "b.npy"), np.full(1000, 6.0))
    r = as_user("gkuser1", "run", g, "--cache", cache, "--out", o1, "--set", "v=5")  # user 2's entries
    assert r.returncode == 0 and "0 computed, 2 cached" in r.stderr, r.stderr
    r = as_user("gkuser1", "cache", "verify", "--cache", cache)
    assert r.returncode == 0 and "0 problems" in r.stdout, r.stdout + r.stderr


def _snapshot(cache):
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in cache.rglob("*")}


def test_read_only_cache_serves_hits(tmp_path, write, users):
    from graphkit import run_graph

    uids, gid = users
    os.chmod(tmp_path, 0o755)
    g = write("g.yaml", G)
    cache = tmp_path / "cache"
    run_graph(g, cache=cache, registry=_registry())  # fully populated (by root)
    subprocess.run(["chmod", "-R", "a-w", str(cache)], check=True)
    try:
        before = _snapshot(cache)
        out = user_dir(tmp_path / "o", uids["gkuser1"], gid)
        r = as_user("gkuser1", "run", g, "--cache", cache, "--out", out)
        assert r.returncode == 0 and "0 computed, 2 cached" in r.stderr, r.stderr
        np.testing.assert_array_equal(np.load(out / "b.npy"), np.full(1000, 3.0))
        r = as_user("gkuser1", "cache", "ls", "--cache", cache)
        assert r.returncode == 0 and "2 entries" in r.stdout, r.stdout + r.stderr
        r = as_user("gkuser1", "cache", "verify", "--cache", cache)
        assert r.returncode == 0 and "0 problems" in r.stdout, r.stdout + r.stderr
        r = as_user("gkuser1", "explain", g, "b", "--cache", cache)
        assert r.returncode == 0 and "is cached" in r.stdout, r.stdout + r.stderr
        # a miss is computed (in memory) and said so; nothing in the cache changes
        r = as_user("gkuser1", "run", g, "--cache", cache, "--out", out, "--set", "v=4")
        assert r.returncode == 0 and "read-only" in r.stderr, r.stderr
        np.testing.assert_array_equal(np.load(out / "b.npy"), np.full(1000, 5.0))
        r = as_user("gkuser1", "cache", "verify", "--repair", "--cache", cache)
        assert r.returncode == 2 and "read-only" in r.stderr, r.stderr
        assert _snapshot(cache) == before
    finally:
        subprocess.run(["chmod", "-R", "u+w", str(cache)], check=True)


def _registry():
    import enginenodes

    from graphkit.registry import discover

    reg = discover()
    reg.add_provider("nodes", "tests", enginenodes)
    return reg
