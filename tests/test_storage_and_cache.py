"""Unit tests of the toolkit's caches (the memoising decorator, the one digest, the disk
cache) and of the Parquet sweep store (round trip bit for bit, every kind of damage
detected, other settings refused, one writer at a time)."""
from __future__ import annotations

import errno
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from analysis.sweeps.storage import SweepStore, SweepStoreError
from biped_casadi.caching import MISSING, ResultStore, cache_key, cached, digest, task_key


# ------------------------------------------------------------------ caching
def test_cached_is_keyed_by_content_and_bounded():
    calls = []

    @dataclass(frozen=True)
    class Thing:
        name: str

        @property
        def cache_key(self):
            return self.name

    @cached(maxsize=2)
    def build(x, n=1):
        calls.append((x, n))
        return object()

    a = build(Thing("a"))
    assert build(Thing("a")) is a and len(calls) == 1        # content-equal: one entry
    build(Thing("b")), build(Thing("a"), n=2)
    assert build.cache_len() == 2                             # bounded: the oldest dropped
    assert build(Thing("a")) is not a and len(calls) == 4
    build.cache_clear()
    assert build.cache_len() == 0
    assert cache_key([1, {"k": (2, 3)}]) == (1, (("k", (2, 3)),))


def test_digest_is_canonical():
    assert digest({"b": 1, "a": [1, 2]}) == digest({"a": [1, 2], "b": 1})
    assert digest({"a": 1}) != digest({"a": 1.5})
    assert len(digest("x")) == 64


def test_the_store_keeps_results_by_key(tmp_path):
    store = ResultStore(tmp_path)
    key = task_key("things", 1, "gait", ({"x": 1},))
    assert task_key("things", 1, "gait", ({"x": 1},)) == key
    assert task_key("things", 1, "gait", ({"x": 2},)) != key        # other inputs
    assert task_key("things", 2, "gait", ({"x": 1},)) != key        # other version
    assert store.path(key).parent == tmp_path / "tasks" / key[:2]
    assert store.path(key, ".json").suffix == ".json" and store.path(key, "").suffix == ""
    assert store.read(key) is MISSING and store.empty()
    assert store.write(key, "things", [1.0, 2.0], 0.5) and not store.empty()
    assert store.read(key) == dict(name="things", value=[1.0, 2.0], seconds=0.5)
    store.path(key).write_bytes(b"damaged")                        # computed again
    assert store.read(key) is MISSING
    assert ResultStore(False).write(key, "things", 1) is False


# ------------------------------------------------------------------ storage
def _chunk(n=5, seed=0):
    rng = np.random.default_rng(seed)
    M1 = rng.uniform(-10, 10, (n, 4))
    status = np.array(["stable", "unstable", "singular", "no_impact", "stable"][:n])
    A = rng.standard_normal((n, 2, 2))
    ev = np.linalg.eigvals(A).astype(complex)
    max_abs = np.abs(ev).max(axis=1)
    A[2], ev[2], max_abs[2] = np.nan, np.nan, np.inf          # the singular row
    ev[0, 1] = complex(-0.0, 0.0)                             # a signed zero survives
    return M1, status, max_abs, A, ev


def test_store_round_trip_is_exact(tmp_path):
    M1, status, max_abs, A, ev = _chunk()
    with SweepStore(tmp_path / "s", {"grid": 9}) as store:
        path = store.write_chunk(0, 10, M1, status, max_abs, A, ev)
        back = store.read_chunk(path, 0, 10, M1)
    assert back["status"].tolist() == status.tolist()
    np.testing.assert_array_equal(back["max_abs"], max_abs)
    np.testing.assert_array_equal(back["A"], A)
    assert np.array_equal(back["eigenvalues"].view(float), ev.view(float), equal_nan=True)
    assert np.signbit(back["eigenvalues"][0, 1].real)
    assert list(store.chunk_files()) == [0]
    meta = json.loads((tmp_path / "s" / "sweep.json").read_text())
    assert meta["settings"] == {"grid": 9} and meta["settings_sha256"] == digest({"grid": 9})


def test_a_full_disk_names_the_chunk_and_leaves_no_partial_file(tmp_path, monkeypatch):
    import errno
    import os
    M1, status, max_abs, A, ev = _chunk()
    with SweepStore(tmp_path / "s", {"grid": 9}) as store:
        def full(fd):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        monkeypatch.setattr(os, "fsync", full)
        with pytest.raises(OSError) as e:
            store.write_chunk(0, 0, M1, status, max_abs, A, ev)
        monkeypatch.undo()
        name = Path(e.value.filename)
        assert name.parent == tmp_path / "s" / "chunks" and name.name.startswith("part-000000.")
        assert list((tmp_path / "s" / "chunks").iterdir()) == []
        assert list(store.chunk_files()) == []
        # a temporary file a killed run left is removed when the folder is opened again
        (tmp_path / "s" / "chunks" / ".part-000001.abc.99.tmp.parquet").write_bytes(b"x")
    with SweepStore(tmp_path / "s", {"grid": 9}):
        assert list((tmp_path / "s" / "chunks").iterdir()) == []


def test_store_detects_every_kind_of_damage(tmp_path):
    M1, status, max_abs, A, ev = _chunk()
    with SweepStore(tmp_path / "s", {"grid": 9}) as store:
        path = store.write_chunk(0, 0, M1, status, max_abs, A, ev)
        data = path.read_bytes()
        # a flipped byte: the name's digest no longer matches
        bad = bytearray(data)
        bad[len(bad) // 2] ^= 0xFF
        path.write_bytes(bytes(bad))
        with pytest.raises(ValueError, match="digest"):
            store.read_chunk(path, 0, 0, M1)
        path.write_bytes(data)
        # the file asked for as another chunk, other rows, or other points
        with pytest.raises(ValueError):
            store.read_chunk(path, 1, 0, M1)
        with pytest.raises(ValueError, match="other rows"):
            store.read_chunk(path, 0, 5, M1)
        with pytest.raises(ValueError, match="expected points"):
            store.read_chunk(path, 0, 0, M1 + 1e-12)
    # written for other settings
    with SweepStore(tmp_path / "t", {"grid": 10}) as other:
        with pytest.raises(ValueError, match="other settings"):
            other.read_chunk(path, 0, 0, M1)


def test_store_refuses_other_settings_foreign_folders_and_a_second_writer(tmp_path):
    with SweepStore(tmp_path / "s", {"grid": 9}):
        with pytest.raises(SweepStoreError, match="in use"):
            SweepStore(tmp_path / "s", {"grid": 9}).open()
    with pytest.raises(SweepStoreError, match="other settings"):
        SweepStore(tmp_path / "s", {"grid": 11}).open()
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    with pytest.raises(SweepStoreError, match="not a sweep folder"):
        SweepStore(tmp_path / "foreign", {"grid": 9}).open()
    assert (tmp_path / "foreign" / "notes.txt").read_text() == "mine"   # untouched


def test_store_log_skips_a_cut_line(tmp_path):
    with SweepStore(tmp_path / "s", {"grid": 9}) as store:
        store.log({"chunk": 0})
        with open(tmp_path / "s" / "log.jsonl", "a") as f:
            f.write('{"chunk": 1')                               # cut by a kill
        assert store.read_log() == [{"chunk": 0}]


def test_cache_dir_names_a_bad_folder(tmp_path):
    from biped_casadi import cache_dir
    with pytest.raises(TypeError, match="^path must be a file name"):
        cache_dir(5)
    assert cache_dir(str(tmp_path)) == cache_dir(tmp_path) == tmp_path


def test_an_atomic_write_creates_missing_folders_and_removes_them_if_it_fails(
        tmp_path, monkeypatch):
    """The folders a failed write created are removed (an earlier one is kept), and the
    error names the file; a folder path through a file is refused."""
    from biped_casadi.files import write_text_atomic
    (tmp_path / "kept").mkdir()
    out = tmp_path / "kept" / "a" / "b" / "x.json"

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with monkeypatch.context() as m:
        m.setattr(os, "fsync", full)
        with pytest.raises(OSError) as e:
            write_text_atomic(out, "{}")
    assert e.value.filename == str(out)
    assert [p.name for p in tmp_path.rglob("*")] == ["kept"]
    assert write_text_atomic(out, "{}") == out and out.read_text() == "{}"
    with pytest.raises(FileExistsError):
        write_text_atomic(out / "y" / "z.json", "{}")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a", "b", "kept", "x.json"]
