"""On-disk layout of an M1 sweep: one Parquet file per chunk of points, a metadata file
with the settings, a run log, and a lock.

    OUT/
      sweep.json              format, version, settings (gait digest, point-set digest,
                              chunk size, map options) and their digest
      chunks/part-000012.<sha>.parquet
                              rows [12 * chunk_size, ...): index, M1, status, max_abs,
                              A^z, eigenvalues; <sha> is the first 16 hex digits of the
                              SHA-256 of the file's own bytes; its key-value metadata
                              holds the settings digest, the row range and a SHA-256 of
                              the decoded contents
      log.jsonl               one line per run: which chunks were found, recomputed
      .lock                   flock held by the running sweep

Every file is written to a temporary name in the same folder and moved into place with
``os.replace``, so a reader (or a rerun after SIGKILL) sees a chunk whole or not at all.
A chunk that fails any check on reading (file bytes not matching the digest in its name,
unreadable Parquet, other settings, wrong rows, M1 not the expected points, contents
checksum mismatch) is reported as corrupt, removed and recomputed.
"""
from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np

from biped_casadi.caching import digest
from biped_casadi.files import write_bytes_atomic

__all__ = ["SweepStore", "SweepStoreError", "FORMAT", "FORMAT_VERSION", "STATUS_CODES",
           "digest_points"]

FORMAT = "biped-casadi-sweep"
FORMAT_VERSION = 1
META = "sweep.json"
LOG = "log.jsonl"
LOCK = ".lock"
CHUNKS = "chunks"
STATUS_CODES = ("stable", "unstable", "singular", "no_impact", "open_orbit")   # theory §4
_KV_KEY = b"biped_sweep"


class SweepStoreError(ValueError):
    """An output folder that cannot be used for this sweep.

    Other settings, not a sweep folder, unreadable metadata, or in use by another run;
    a ``ValueError``.
    """


def digest_points(points: np.ndarray) -> str:
    """SHA-256 of an (n, nu) float64 array (little-endian, C order) and its shape."""
    p = np.ascontiguousarray(points, dtype="<f8")
    h = hashlib.sha256(f"{p.shape}".encode())
    h.update(p.tobytes())
    return h.hexdigest()


def _content_digest(index, M1, status_code, max_abs, A, eigenvalues) -> str:
    h = hashlib.sha256()
    for a in (np.asarray(index, "<i8"), np.asarray(M1, "<f8"), np.asarray(status_code, "u1"),
              np.asarray(max_abs, "<f8"), np.asarray(A, "<f8"),
              np.asarray(eigenvalues, "<c16")):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


class SweepStore:
    """A sweep's output folder.  ``open`` creates or checks it (refusing other settings)
    and takes the lock; ``valid_chunks`` reads back what is stored; ``write_chunk`` adds
    one chunk atomically."""

    #: the folder's kind, format version, metadata file and Parquet key-value key (a
    #: subclass stores other results in the same layout)
    FORMAT, FORMAT_VERSION, META, KV_KEY, KIND = FORMAT, FORMAT_VERSION, META, _KV_KEY, "sweep"

    def __init__(self, root, settings: dict):
        self.root = Path(root)
        self.settings = settings
        self.digest = digest(settings)
        self.chunk_dir = self.root / CHUNKS
        self._lock_fd = None

    # ------------------------------------------------------------------ open
    def open(self):
        root = self.root
        if root.exists() and not root.is_dir():
            raise SweepStoreError(f"out: {root} exists and is not a folder")
        root.mkdir(parents=True, exist_ok=True)
        meta_path = root / self.META
        if meta_path.exists():
            self._check_meta(meta_path)
        else:
            stray = [p.name for p in root.iterdir() if p.name not in (LOCK, CHUNKS)]
            if stray or (self.chunk_dir.exists() and any(self.chunk_dir.iterdir())):
                raise SweepStoreError(
                    f"out: {root} is not empty and holds no {self.META}; it is not a "
                    f"{self.KIND} folder (choose an empty or new folder)")
        self._lock()
        if not meta_path.exists():
            body = dict(format=self.FORMAT, version=self.FORMAT_VERSION, settings=self.settings,
                        settings_sha256=self.digest,
                        created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
            write_bytes_atomic(meta_path, (json.dumps(body, indent=1) + "\n").encode())
        self.chunk_dir.mkdir(exist_ok=True)
        for p in self.chunk_dir.glob(".*.tmp*"):     # left by a killed run
            p.unlink(missing_ok=True)
        return self

    def _check_meta(self, meta_path: Path):
        try:
            body = json.loads(meta_path.read_text())
            fmt, ver, stored = body["format"], body["version"], body["settings"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise SweepStoreError(f"out: {meta_path} is unreadable ({e}); not resuming into "
                                  f"it (choose another folder)") from None
        if fmt != self.FORMAT:
            raise SweepStoreError(f"out: {meta_path} is not a {self.FORMAT} file")
        if ver != self.FORMAT_VERSION:
            raise SweepStoreError(f"out: {self.root} was written in {self.KIND} format version "
                                  f"{ver!r}; this toolkit writes version {self.FORMAT_VERSION} "
                                  f"(choose another folder)")
        if digest(stored) != self.digest:
            diff = sorted(k for k in set(stored) | set(self.settings)
                          if stored.get(k) != self.settings.get(k))
            hint = (" (the analysis code changed since it was written)"
                    if "code_sha256" in diff else "")
            raise SweepStoreError(
                f"out: {self.root} holds a {self.KIND} made with other settings (differ in: "
                f"{', '.join(diff)}){hint}; refusing to mix results: use another folder")

    def _lock(self):
        fd = os.open(self.root / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise SweepStoreError(f"out: {self.root} is in use by another running "
                                      f"{self.KIND}") from None
            raise
        self._lock_fd = fd

    def close(self):
        if self._lock_fd is not None:
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    # ---------------------------------------------------------------- chunks
    def chunk_files(self) -> dict[int, list[Path]]:
        """Stored chunk files by chunk number (normally one each)."""
        out: dict[int, list[Path]] = {}
        for p in sorted(self.chunk_dir.glob("part-*.parquet")):
            try:
                k = int(p.name.split(".")[0].split("-")[1])
            except (IndexError, ValueError):
                k = -1
            out.setdefault(k, []).append(p)
        return out

    def write_chunk(self, k: int, start: int, M1, status, max_abs, A, eigenvalues):
        import pyarrow as pa
        n = len(M1)
        index = np.arange(start, start + n, dtype=np.int64)
        code = np.array([STATUS_CODES.index(s) for s in status], dtype=np.uint8)
        M1, A = np.asarray(M1, float), np.asarray(A, float).reshape(n, 2, 2)
        ev = np.asarray(eigenvalues, complex).reshape(n, 2)
        max_abs = np.asarray(max_abs, float)
        cols = {"index": index}
        cols.update({f"M1_{j + 1}": M1[:, j] for j in range(M1.shape[1])})
        cols["status"] = pa.array([STATUS_CODES[c] for c in code], pa.string())
        cols["max_abs"] = max_abs
        cols.update({f"A_{i + 1}{j + 1}": A[:, i, j] for i in range(2) for j in range(2)})
        for i in range(2):
            cols[f"lambda{i + 1}_re"] = ev[:, i].real.copy()
            cols[f"lambda{i + 1}_im"] = ev[:, i].imag.copy()
        return self.write_table(k, start, start + n, cols,
                                _content_digest(index, M1, code, max_abs, A, ev))

    def write_table(self, k: int, start: int, stop: int, cols: dict, content_sha256: str):
        """Write chunk ``k`` (rows ``start:stop``) of columns ``cols`` atomically, with
        the settings digest, the row range and ``content_sha256`` in its metadata and
        the SHA-256 of its bytes in its name; returns the path."""
        import pyarrow as pa
        import pyarrow.parquet as pq
        info = dict(settings_sha256=self.digest, chunk=k, start=start, stop=stop,
                    content_sha256=content_sha256)
        table = pa.table(cols).replace_schema_metadata({self.KV_KEY: json.dumps(info).encode()})
        buf = pa.BufferOutputStream()
        pq.write_table(table, buf, compression="zstd", write_page_checksum=True)
        data = buf.getvalue().to_pybytes()
        sha = hashlib.sha256(data).hexdigest()[:16]
        path = self.chunk_dir / f"part-{k:06d}.{sha}.parquet"
        write_bytes_atomic(path, data)      # a failed write names the chunk
        return path

    def read_table(self, path: Path, k: int, start: int, n: int):
        """Read chunk ``k``'s file ``path`` and check its bytes, its Parquet checksums,
        its settings and its rows ``start:start+n``; returns (table, metadata) or
        raises ValueError saying what is wrong."""
        import pyarrow as pa
        import pyarrow.parquet as pq
        path = Path(path)
        data = path.read_bytes()
        parts = path.name.split(".")
        if len(parts) != 3 or parts[0] != f"part-{k:06d}" or \
                hashlib.sha256(data).hexdigest()[:16] != parts[1]:
            raise ValueError("file bytes do not match the digest in its name")
        try:
            table = pq.read_table(pa.BufferReader(data), page_checksum_verification=True)
        except Exception as e:          # noqa: BLE001 - any read failure means corrupt
            raise ValueError(f"unreadable Parquet ({type(e).__name__}: {e})") from None
        try:
            info = json.loads((table.schema.metadata or {})[self.KV_KEY])
        except (KeyError, ValueError):
            raise ValueError(f"no {self.KIND} metadata in the file") from None
        if info.get("settings_sha256") != self.digest:
            raise ValueError("written for other settings")
        if (info.get("chunk"), info.get("start"), info.get("stop")) != (k, start, start + n):
            raise ValueError("holds other rows than expected")
        if table.num_rows != n:
            raise ValueError(f"has {table.num_rows} rows, expected {n}")
        return table, info

    def read_chunk(self, path: Path, k: int, start: int, points: np.ndarray) -> dict:
        """Read and check the file ``path`` of chunk ``k`` (rows
        ``start:start+len(points)``); raises ValueError saying what is wrong."""
        n = len(points)
        table, info = self.read_table(path, k, start, n)
        try:
            col = {name: table.column(name).to_numpy(zero_copy_only=False)
                   for name in table.column_names}
            index = col["index"].astype(np.int64)
            M1 = np.stack([col[f"M1_{j + 1}"] for j in range(points.shape[1])],
                          axis=1).astype(float)
            status = np.array(col["status"], dtype=object).astype(str)
            code = np.array([STATUS_CODES.index(s) for s in status], dtype=np.uint8)
            max_abs = col["max_abs"].astype(float)
            A = np.stack([col[f"A_{i + 1}{j + 1}"] for i in range(2) for j in range(2)],
                         axis=1).reshape(n, 2, 2).astype(float)
            ev = np.empty((n, 2), dtype=complex)
            for i in range(2):       # component-wise: keeps signed zeros and NaN bits
                ev.real[:, i] = col[f"lambda{i + 1}_re"]
                ev.imag[:, i] = col[f"lambda{i + 1}_im"]
        except (KeyError, ValueError) as e:
            raise ValueError(f"missing or bad columns ({e})") from None
        if not np.array_equal(index, np.arange(start, start + n)):
            raise ValueError("row indices are not the expected ones")
        if not np.array_equal(M1, points):
            raise ValueError("M1 values are not the expected points")
        if _content_digest(index, M1, code, max_abs, A, ev) != info.get("content_sha256"):
            raise ValueError("content checksum mismatch")
        return dict(status=status, max_abs=max_abs, A=A, eigenvalues=ev)

    @staticmethod
    def discard(path: Path):
        Path(path).unlink(missing_ok=True)

    # ------------------------------------------------------------------- log
    def log(self, record: dict):
        """Append one JSON line to log.jsonl (a line cut by SIGKILL is skipped on read)."""
        with open(self.root / LOG, "a") as f:
            f.write(json.dumps(record) + "\n")

    def read_log(self) -> list[dict]:
        path = self.root / LOG
        if not path.exists():
            return []
        out = []
        for line in path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                pass
        return out
