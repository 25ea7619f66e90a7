"""Records, journals and entries are untrusted input (issue 29, item 6): a second user of a
group-writable cache can write anything into it.  A digest that is not the exact hex form is
damage, never a path; nothing outside the cache root is opened, moved or deleted because of what
an entry says; a forged record that passes every check is served unless the keyed check
(GRAPHKIT_CACHE_KEY) is on."""
import json
import os

import numpy as np
import pytest
import xxhash

from conftest import engine_env, graphkit
from test_engine_trust import TWO, manifest, rec_path, record_bytes, replace_record

ENV = engine_env({"GRAPHKIT_PLUGINS": "enginenodes,storenodes"})


def gk(*args, env=ENV):
    return graphkit(*args, env=env)


def run_ok(g, cache, out, env=ENV):
    r = gk("run", g, "--cache", cache, "--out", out, "--jobs", "1", env=env)
    assert r.returncode == 0, r.stderr
    return r


def signed(rec: dict) -> bytes:
    """A record with a correct check line, as anyone who can write the folder can make one."""
    body = json.dumps(rec, sort_keys=True, separators=(",", ":")).encode()
    return b"GKREC1 " + xxhash.xxh3_128_hexdigest(body).encode() + b"\n" + body


def forged(cache, key, digest) -> bytes:
    rec = json.loads(record_bytes(cache, key).split(b"\n", 1)[1])
    rec["outputs"]["out"]["digest"] = digest
    return signed(rec)


@pytest.fixture
def victim(tmp_path, write):
    """A graph run once into a cache, and a file of the cache's user outside the cache."""
    home = tmp_path / "homeA"
    home.mkdir()
    notes = home / "notes.txt"
    notes.write_bytes(b"my own notes")
    g, cache, out = write("g.yaml", TWO), tmp_path / "c", tmp_path / "o"
    run_ok(g, cache, out)
    return g, cache, out, notes, manifest(out)["nodes"]["x"]["key"]


def assert_untouched_and_recomputed(g, cache, out, notes, key):
    r = run_ok(g, cache, out)
    assert notes.read_bytes() == b"my own notes"
    np.testing.assert_array_equal(np.load(out / "x.npy"), np.full(64, 1.0))
    assert manifest(out)["nodes"]["x"]["hit"] is False
    said = [ln for ln in r.stderr.splitlines() if key[:16] in ln]
    assert len(said) == 1 and "quarantine" in said[0], r.stderr
    assert gk("cache", "gc", "--cache", cache, "--max-size", "0").returncode == 0
    assert notes.read_bytes() == b"my own notes"


@pytest.mark.parametrize("digest", ["../homeA/notes.txt", "", "/etc/passwd",
                                    "AB" * 16, "ab" * 16 + "/..", 12345, None])
def test_a_digest_that_is_not_one_is_damage_never_a_path(victim, digest):
    g, cache, out, notes, key = victim
    replace_record(cache, key, forged(cache, key, digest))
    v = gk("cache", "verify", "--cache", cache)
    assert v.returncode == 1 and "output digest that is not one" in v.stdout + v.stderr, v.stdout + v.stderr
    assert_untouched_and_recomputed(g, cache, out, notes, key)
    assert list(notes.parent.iterdir()) == [notes]


def test_a_forged_frame_appended_to_a_journal_is_damage(victim):
    g, cache, out, notes, key = victim
    journal = os.path.realpath(rec_path(cache, key))
    assert os.stat(journal).st_nlink > 1  # the record is a link to the run's journal
    raw = forged(cache, key, "../homeA/notes.txt")
    with open(rec_path(cache, key), "ab") as f:  # a later frame of a key wins
        f.write(b"\0GKJF %s %d\n" % (key.encode(), len(raw)) + raw)
    assert_untouched_and_recomputed(g, cache, out, notes, key)


def test_a_record_that_is_a_link_out_of_the_cache_is_not_followed(victim):
    g, cache, out, notes, key = victim
    p = rec_path(cache, key)
    p.unlink()
    os.symlink(notes, p)
    assert_untouched_and_recomputed(g, cache, out, notes, key)


def test_a_record_that_is_a_fifo_does_not_hang_the_run(victim):
    g, cache, out, notes, key = victim
    p = rec_path(cache, key)
    p.unlink()
    os.mkfifo(p)
    assert_untouched_and_recomputed(g, cache, out, notes, key)


def test_an_object_that_is_a_link_out_of_the_cache_is_not_followed(victim):
    g, cache, out, notes, key = victim
    d = manifest(out)["nodes"]["x"]["outputs"]["out"]
    p = cache / "objects" / d[:2] / d
    p.unlink()
    os.symlink(notes, p)
    r = run_ok(g, cache, out)
    assert "quarantine" in r.stderr and notes.read_bytes() == b"my own notes"
    np.testing.assert_array_equal(np.load(out / "x.npy"), np.full(64, 1.0))
    assert gk("cache", "verify", "--cache", cache).returncode == 0


@pytest.mark.parametrize("part", ["quarantine", "tmp", "objects", "keys", "journal"])
def test_gc_never_deletes_through_a_folder_replaced_by_a_link(victim, part):
    g, cache, out, notes, key = victim
    gone = cache / part
    if gone.exists():
        os.rename(gone, cache / f"{part}.old")
    os.symlink(notes.parent, gone)
    gk("cache", "gc", "--cache", cache, "--max-size", "0")
    gk("cache", "verify", "--repair", "--cache", cache)
    assert notes.read_bytes() == b"my own notes"


def test_a_shared_cache_trusts_its_writers_unless_keyed(tmp_path, write):
    """A record swapped with a recomputed check line (x's record naming y's object) is served, as
    with any shared build cache; with GRAPHKIT_CACHE_KEY set, only records written by runs holding
    the key are: the forgery is quarantined and x recomputed."""
    g, cache, out = write("g.yaml", TWO), tmp_path / "c", tmp_path / "o"
    keyed = {**ENV, "GRAPHKIT_CACHE_KEY": "team secret"}
    for env, served in ((ENV, True), (keyed, False)):
        if cache.exists():
            gk("cache", "gc", "--cache", cache, "--max-size", "0")
        run_ok(g, cache, out, env)
        m = manifest(out)["nodes"]
        kx, dy = m["x"]["key"], m["y"]["outputs"]["out"]
        assert (record_bytes(cache, kx).split(b"\n", 1)[0].count(b" ") == 2) is (env is keyed)
        replace_record(cache, kx, forged(cache, kx, dy))
        r = run_ok(g, cache, out, env)
        x = np.load(out / "x.npy")
        assert bool(x[0] == 7.0) is served, r.stderr
        assert manifest(out)["nodes"]["x"]["hit"] is served
        if not served:
            assert "GRAPHKIT_CACHE_KEY" in r.stderr and "quarantine" in r.stderr, r.stderr


def test_keyed_records_read_without_the_key_and_the_wrong_key_recomputes(tmp_path, write):
    g, cache, out = write("g.yaml", TWO), tmp_path / "c", tmp_path / "o"
    run_ok(g, cache, out, {**ENV, "GRAPHKIT_CACHE_KEY": "k1"})
    run_ok(g, cache, out)  # a run without the key still checks the check line, and serves
    assert all(n["hit"] for n in manifest(out)["nodes"].values())
    run_ok(g, cache, out, {**ENV, "GRAPHKIT_CACHE_KEY": "k2"})
    assert not any(n["hit"] for n in manifest(out)["nodes"].values())
    v = gk("cache", "verify", "--cache", cache, env={**ENV, "GRAPHKIT_CACHE_KEY": "k2"})
    assert v.returncode == 0, v.stdout + v.stderr
