"""The on-disk text-embedding cache: hits, misses, invalidation, corruption, bounds."""

from __future__ import annotations

import hashlib
import logging
import multiprocessing as mp
from pathlib import Path

import numpy as np
import pytest

from quash_plugins.core.interfaces import Encoder
from quash_plugins.engine.cache import TextEmbeddingCache, default_cache_dir


class CountingEncoder(Encoder):
    """Hash-seeded unit vectors; records every string that reaches the 'model'."""

    name = "counting"

    def __init__(self, dim: int = 8, version: str = "a") -> None:
        self._dim = dim
        self.version = version
        self.calls: list[list[str]] = []

    @property
    def dim(self) -> int:
        return self._dim

    def encode_text(self, texts):
        self.calls.append(list(texts))
        rows = []
        for t in texts:
            seed = int.from_bytes(
                hashlib.sha256(f"{self.version}|{t}".encode()).digest()[:8], "little"
            )
            v = np.random.default_rng(seed).normal(size=self._dim)
            rows.append(v / np.linalg.norm(v))
        return np.asarray(rows, dtype=np.float32).reshape(len(texts), self._dim)

    def config(self):
        return {"version": self.version}

    @property
    def n_encoded(self) -> int:
        return sum(len(c) for c in self.calls)


def _vec(seed: int, d: int = 4) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=d).astype(np.float32)


def test_default_dir_honours_env(monkeypatch, tmp_path):
    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path / "x"))
    assert default_cache_dir() == tmp_path / "x" / "text-embeddings"
    assert TextEmbeddingCache().directory == tmp_path / "x" / "text-embeddings"
    assert TextEmbeddingCache(tmp_path / "y").directory == tmp_path / "y"
    monkeypatch.delenv("QUASH_CACHE_DIR")
    import platformdirs

    assert default_cache_dir().parent == Path(platformdirs.user_cache_dir("quash-plugins"))


def test_store_lookup_roundtrip_exact_strings(tmp_path):
    cache = TextEmbeddingCache(tmp_path)
    data = {t: _vec(i) for i, t in enumerate(["chair", "Chair", "chair ", "a chair", "é"])}
    cache.store("fp-1", data)
    got = TextEmbeddingCache(tmp_path).lookup("fp-1", [*data, "sofa"])
    assert set(got) == set(data)  # exact strings: case and spaces matter, sofa is a miss
    for t, v in data.items():
        assert got[t].dtype == np.float32 and got[t].shape == (4,)
        np.testing.assert_array_equal(got[t], v)


def test_fingerprint_change_invalidates(tmp_path):
    cache = TextEmbeddingCache(tmp_path)
    cache.store("fp-1", {"chair": _vec(1)})
    assert cache.lookup("fp-2", ["chair"]) == {}
    assert cache.hits == 0 and cache.misses == 1


def test_odd_fingerprints_are_safe_file_names(tmp_path):
    cache = TextEmbeddingCache(tmp_path)
    for fp in ("../../evil", "a/b", ".hidden", "x" * 300):
        cache.store(fp, {"chair": _vec(2)})
        np.testing.assert_array_equal(cache.lookup(fp, ["chair"])["chair"], _vec(2))
    assert all(p.is_relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert not (tmp_path.parent / "evil").exists()


def test_pipeline_second_encode_makes_no_model_call(tmp_path):
    from quash_plugins.core.text import encode_texts

    enc = CountingEncoder()
    cache = TextEmbeddingCache(tmp_path)
    first = encode_texts(enc, ["chair", "sofa", "chair"], cache)
    assert enc.calls == [["chair", "sofa"]]
    second = encode_texts(enc, ["sofa", "chair"], cache)
    assert enc.n_encoded == 2
    np.testing.assert_array_equal(second, first[[1, 0]])
    encode_texts(CountingEncoder(version="b"), ["chair"], cache)  # new fingerprint: a miss
    assert cache.misses == 2 + 1


def test_repeated_query_with_templates_is_served_from_cache(tmp_path):
    """Through Quash with prompt templates: the second identical query encodes nothing."""
    from quash_plugins import Quash
    from quash_plugins.core import registry
    from quash_plugins.core.types import LatentMap

    templates = ["a photo of a {}.", "a {} in a room.", "there is a {} here."]
    enc = CountingEncoder()
    rng = np.random.default_rng(0)
    E = rng.normal(size=(50, 8)).astype(np.float32)
    lmap = LatentMap(E)

    def quash():
        return Quash(
            enc,
            classifier=registry.create("classifiers", "contrast"),
            negatives=["other", "background"],
            prompt_templates={"mode": "all", "templates": templates},
            cache=TextEmbeddingCache(tmp_path),
            instances=False,
        )

    q1 = quash()
    r1 = q1.query(lmap, "chair")
    strings = {t.format(w) for w in ("chair", "other", "background") for t in templates}
    assert {s for c in enc.calls for s in c} == strings
    n_first = enc.n_encoded
    q2 = quash()  # a new pipeline (as a new process would build), same cache directory
    r2 = q2.query(lmap, "chair")
    assert enc.n_encoded == n_first
    assert q2.cache.hits == len(strings) and q2.cache.misses == 0
    np.testing.assert_array_equal(r1.scores, r2.scores)


def test_corrupt_file_is_reported_rebuilt_and_never_fatal(tmp_path, caplog):
    from quash_plugins.core.text import encode_texts

    enc = CountingEncoder()
    cache = TextEmbeddingCache(tmp_path)
    ref = encode_texts(enc, ["chair", "sofa", "lamp"], cache)
    files = sorted(tmp_path.rglob("*.npz"))
    assert files
    for i, f in enumerate(files):  # truncated, garbage, and bit-flipped files
        raw = f.read_bytes()
        f.write_bytes(raw[: len(raw) // 2] if i % 2 == 0 else b"not an npz at all")
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.cache"):
        again = encode_texts(enc, ["chair", "sofa", "lamp"], TextEmbeddingCache(tmp_path))
    np.testing.assert_allclose(again, ref)
    assert "corrupt" in caplog.text
    assert enc.n_encoded == 6  # everything re-encoded once
    third = TextEmbeddingCache(tmp_path)
    encode_texts(enc, ["chair", "sofa", "lamp"], third)  # rebuilt: now all hits
    assert enc.n_encoded == 6 and third.hits == 3 and not third.corrupt


def test_checksum_catches_silent_value_changes(tmp_path, caplog):
    cache = TextEmbeddingCache(tmp_path)
    cache.store("fp", {"chair": _vec(1)})
    (f,) = tmp_path.rglob("*.npz")
    with np.load(f) as z:
        parts = {k: z[k] for k in z.files}
    parts["embeddings"] = parts["embeddings"] + 1.0
    np.savez(f, **parts)
    with caplog.at_level(logging.WARNING):
        assert cache.lookup("fp", ["chair"]) == {}
    assert "checksum" in caplog.text and cache.corrupt == [f]
    assert not f.exists()


def test_bounded_lru_eviction(tmp_path):
    import os

    cache = TextEmbeddingCache(tmp_path, max_bytes=10**9)
    big = {f"w{i}": _vec(i, 256) for i in range(200)}
    cache.store("old", big)
    cache.store("new", big)
    per_fp = cache.info()["encoders"][0]["bytes"]
    # Make "old" the least recently used, then bound the cache to about one fingerprint.
    for f in (tmp_path / "v1" / "old").glob("*.npz"):
        os.utime(f, (1, 1))
    cache.max_bytes = int(per_fp * 1.2)
    cache.store("new", {"extra": _vec(0, 256)})
    info = cache.info()
    assert info["bytes"] <= cache.max_bytes
    assert len(cache.lookup("new", list(big))) == len(big)
    assert len(cache.lookup("old", list(big))) < len(big)


def test_info_and_clear(tmp_path):
    cache = TextEmbeddingCache(tmp_path)
    assert cache.info()["entries"] == 0
    cache.store("fp-a", {"chair": _vec(1), "sofa": _vec(2)})
    cache.store("fp-b", {"chair": _vec(3)})
    info = cache.info()
    assert info["entries"] == 3 and info["directory"] == str(tmp_path)
    assert {e["fingerprint"]: e["entries"] for e in info["encoders"]} == {"fp-a": 2, "fp-b": 1}
    assert info["bytes"] == sum(p.stat().st_size for p in tmp_path.rglob("*.npz"))
    assert cache.clear("fp-a") > 0
    assert cache.lookup("fp-a", ["chair"]) == {} and "chair" in cache.lookup("fp-b", ["chair"])
    assert cache.clear() > 0
    assert cache.info()["entries"] == 0 and not list(tmp_path.rglob("*.npz"))


def test_unwritable_directory_never_breaks_encoding(tmp_path):
    from quash_plugins.core.text import encode_texts

    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    cache = TextEmbeddingCache(blocker / "cache")
    out = encode_texts(CountingEncoder(), ["chair"], cache)
    assert out.shape == (1, 8)


def _writer(directory: str, worker: int, n: int) -> None:
    cache = TextEmbeddingCache(directory)
    for i in range(n):
        # every worker writes its own strings and a shared one, in many small stores
        cache.store("fp", {f"w{worker}-{i}": _vec(1000 * worker + i), "shared": _vec(7)})


@pytest.mark.slow
def test_concurrent_processes_lose_nothing(tmp_path):
    methods = mp.get_all_start_methods()
    ctx = mp.get_context("fork" if "fork" in methods else "spawn")
    procs = [ctx.Process(target=_writer, args=(str(tmp_path), w, 25)) for w in range(3)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    cache = TextEmbeddingCache(tmp_path)
    wanted = [f"w{w}-{i}" for w in range(3) for i in range(25)] + ["shared"]
    got = cache.lookup("fp", wanted)
    assert set(got) == set(wanted) and not cache.corrupt
    np.testing.assert_array_equal(got["w2-24"], _vec(2024))


@pytest.mark.parametrize("umask", [0o022, 0o002, 0o000])
def test_cache_folders_are_private_whatever_the_umask(tmp_path, umask):
    """On a shared machine the cache's folders were 0755 (0775, 0777 under a group or
    open umask): others could read the cached strings or plant embeddings. Each folder
    the cache makes is 0700 now; one that exists keeps its mode."""
    import os
    import stat

    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o1777)  # a folder everyone may write into, like /tmp
    old = os.umask(umask)
    try:
        TextEmbeddingCache(shared / "quash" / "text-embeddings").store("fp-1", {"chair": _vec(0)})
    finally:
        os.umask(old)
    made = [shared / "quash", shared / "quash" / "text-embeddings"]
    made += [p for p in (shared / "quash").rglob("*") if p.is_dir()]
    assert len(made) >= 4  # the root, text-embeddings, v1 and the fingerprint's folder
    for folder in made:
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700, folder
    assert stat.S_IMODE(shared.stat().st_mode) == 0o1777  # not made here: left alone


def test_clear_deletes_only_the_caches_own_files(tmp_path, capsys):
    """'quash cache clear --dir DIR' deleted every 'v<N>' folder whole: a project's
    'v1/notes.txt' went with it. Only shards and their locks go; the rest stays."""
    from quash_plugins.cli.main import main
    from quash_plugins.engine.cache import TextEmbeddingCache

    cache = TextEmbeddingCache(tmp_path)
    cache.store("enc-1", {"chair": np.array([0.6, 0.8], np.float32)})
    notes = tmp_path / "v1" / "notes.txt"
    notes.write_text("important")
    project = tmp_path / "v2" / "data"
    project.mkdir(parents=True)
    (project / "scan.npz").write_bytes(b"")  # a user's file named like a shard, one level up
    (tmp_path / "v2" / "keep.txt").write_text("mine")
    assert main(["-q", "cache", "clear", "--dir", str(tmp_path)]) == 0
    assert notes.read_text() == "important" and (tmp_path / "v2" / "keep.txt").exists()
    assert not list((tmp_path / "v1").glob("*/*.npz"))  # the shard went
    assert cache.lookup("enc-1", ["chair"]) == {}


def test_clearing_an_unknown_fingerprint_says_so(tmp_path, capsys):
    from quash_plugins.cli.main import main
    from quash_plugins.engine.cache import TextEmbeddingCache

    TextEmbeddingCache(tmp_path).store("enc-1", {"chair": np.array([1.0, 0.0], np.float32)})
    code = main(["-q", "cache", "clear", "--dir", str(tmp_path), "--fingerprint", "bogus"])
    assert code == 2
    err = capsys.readouterr().err
    assert "No fingerprint 'bogus'" in err and "Cached: enc-1" in err
    assert TextEmbeddingCache(tmp_path).lookup("enc-1", ["chair"])  # nothing was cleared


def test_a_long_text_is_embedded_but_not_cached(tmp_path):
    """One 120,000-character query widened every text of its shard to its width (a
    fixed-width array): the shard grew to gigabytes and eviction emptied the cache."""
    from quash_plugins.engine.cache import MAX_CACHED_CHARS, TextEmbeddingCache

    cache = TextEmbeddingCache(tmp_path)
    long = "chair " * 20_000
    cache.store("enc-1", {"chair": np.array([1.0, 0.0], np.float32), long: np.ones(2, np.float32)})
    assert set(cache.lookup("enc-1", ["chair", long])) == {"chair"}
    assert len(long) > MAX_CACHED_CHARS
    assert sum(p.stat().st_size for p in tmp_path.rglob("*.npz")) < 10_000


def test_a_query_of_more_than_a_thousand_characters_is_refused():
    from quash_plugins.core.errors import QuashError
    from quash_plugins.core.types import MAX_QUERY_CHARS, check_query

    assert check_query("x" * MAX_QUERY_CHARS)
    with pytest.raises(QuashError, match="characters long .*a query is a word or phrase"):
        check_query("chair " * 20_000)


@pytest.mark.parametrize("value", ["1", "true", "yes", "0", "false", "no", "off", ""])
def test_quash_no_cache_turns_the_cache_off_only_when_it_says_so(monkeypatch, tmp_path, value):
    """docs/encoders.md: QUASH_NO_CACHE=1 turns the cache off; QUASH_NO_CACHE=0 (a user
    turning it back on over an environment that sets it) also turned it off."""
    from quash_plugins.engine.cache import open_cache

    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("QUASH_NO_CACHE", value)
    cache = open_cache(True)
    if value in ("1", "true", "yes"):
        assert cache is None
    else:
        assert isinstance(cache, TextEmbeddingCache)
        assert cache.directory == tmp_path / "text-embeddings"
