"""Content-addressed storage of domains and job results in ``data_dir``.

Layout (shared by every API and worker process, possibly on several machines)::

    domains/<id>.npz       Domain.to_arrays()            (what workers rebuild from)
    domains/<id>.aux.npz   areas, component labels, points (cheap input validation)
    domains/<id>.json      kind, parameters, summary      (written last: marks complete)
    results/<job>.json     result payload (scalars, array descriptions); a small result
                           without arrays or files is kept in its job row instead (IN_ROW)
    results/<job>.npz      result arrays (per vertex / per face / ...): an uncompressed zip
                           of .npy files (``np.savez``), served member by member

Every file is written to a temporary name and renamed into place, so readers
never see partial files; a domain's id is ``Domain.content_hash()``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import struct
import tempfile
import threading
import time
import zipfile
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from service.errors import NotFound
from service.export import to_jsonable as jsonable
from service.schemas import DOMAIN_ID_PATTERN
from solvers.domains import Domain, domain_from_arrays, kind_supports

_ID = re.compile(DOMAIN_ID_PATTERN)
_FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
IN_ROW = "row"  # result_location of a result kept in the job row (column ``result``)
ROW_RESULT_BYTES = 16 * 1024  # largest result JSON kept in the row


def atomic_write(path: Path, write, durable: bool = True) -> None:
    """Write through ``write(fileobj)`` to a temporary file, then rename onto ``path``.

    Readers see the old file or the complete new one, never a partial file, also if the
    writing process dies. ``durable`` also fsyncs before the rename (survives a machine
    crash, at a few milliseconds per file).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _write_json(path: Path, payload, durable: bool = True) -> None:
    atomic_write(path, lambda fh: fh.write(json.dumps(payload).encode()), durable)


def _write_npz(path: Path, arrays: dict[str, np.ndarray], durable: bool = True) -> None:
    atomic_write(path, lambda fh: np.savez(fh, **arrays), durable)


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


@dataclass(frozen=True)
class StoredArray:
    """One result array as a member of its job's .npz: shape, dtype, and where its bytes lie.

    ``data_offset`` (absolute, in the archive) is set when the member is stored uncompressed
    with a C-order array (what ``np.savez`` writes), so rows are read without the rest."""

    name: str
    shape: tuple[int, ...]
    dtype: np.dtype
    npy_bytes: int  # size of the member: the .npy file (header + data)
    data_offset: int | None = None

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))


_LOCAL_HEADER = struct.Struct("<4s5H3I2H")  # zip local file header (30 bytes)


def _npz_index(path: Path) -> dict[str, StoredArray]:
    """The arrays of an .npz, from the zip directory and each member's .npy header only."""
    out = {}
    with open(path, "rb") as fh, zipfile.ZipFile(fh) as archive:
        for info in archive.infolist():
            if not info.filename.endswith(".npy"):
                continue
            name = info.filename[:-len(".npy")]
            with archive.open(info) as member:
                version = np.lib.format.read_magic(member)
                if version == (1, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_1_0(member)
                else:
                    shape, fortran, dtype = np.lib.format.read_array_header_2_0(member)
                header = member.tell()
            offset = None
            if info.compress_type == zipfile.ZIP_STORED and not fortran and not dtype.hasobject:
                fh.seek(info.header_offset)
                fields = _LOCAL_HEADER.unpack(fh.read(_LOCAL_HEADER.size))
                offset = info.header_offset + _LOCAL_HEADER.size + fields[-2] + fields[-1]
                offset += header
            out[name] = StoredArray(name, tuple(int(n) for n in shape), dtype,
                                    int(info.file_size), offset)
    return out


def domain_points(domain: Domain) -> np.ndarray | None:
    """Coordinates of the mass-carrying points (unit-area scale), if the domain has any
    (``Domain.coordinates``)."""
    return domain.coordinates


@dataclass
class DomainInfo:
    """What the API needs to validate a request without building operators."""

    id: str
    meta: dict
    _store: Store

    @property
    def kind(self) -> str:
        return self.meta["kind"]

    @property
    def n(self) -> int:
        return int(self.meta["summary"]["n"])

    def supports(self, capability: str) -> bool:
        """Whether the stored domain has ``capability`` (as ``Domain.supports``)."""
        return kind_supports(self.kind, capability)

    @property
    def n_components(self) -> int:
        return int(self.meta["summary"].get("components", 1))

    @cached_property
    def memo(self) -> dict:
        """Values derived from this stored domain during validation (resolved bumps)."""
        return {}

    @cached_property
    def aux(self) -> dict[str, np.ndarray]:
        return self._store._load_npz(self._store.domain_dir / f"{self.id}.aux.npz", self.id)

    @property
    def areas(self) -> np.ndarray:
        return self.aux["areas"]

    @property
    def component_labels(self) -> np.ndarray:
        return self.aux["component_labels"]

    @property
    def points(self) -> np.ndarray | None:
        return self.aux.get("points")

    @cached_property
    def arrays(self) -> dict[str, np.ndarray]:
        return self._store.domain_arrays(self.id)

    @property
    def artifacts(self) -> DomainArtifacts:
        """The stored domain's artifacts (:meth:`Store.domain_artifacts`)."""
        return self._store.domain_artifacts(self.id)


class DomainArtifacts:
    """A stored domain's artifact store (:class:`solvers.domains.operators.ArtifactStore`):
    ``.npy`` files in ``artifacts/<domain id>/`` beside the domain, named by key (the key
    names the array and its method, the folder the domain's content), written atomically and
    memory-mapped read-only when read."""

    def __init__(self, folder: Path):
        self.folder = folder

    def _path(self, key: str) -> Path:
        if not _FILE_NAME.match(key):
            raise ValueError(f"bad artifact key {key!r}")
        return self.folder / f"{key}.npy"

    def get(self, key: str) -> np.ndarray | None:
        """The array ``key``, memory-mapped read-only, or None where it is not stored."""
        try:
            return np.load(self._path(key), mmap_mode="r", allow_pickle=False)
        except FileNotFoundError:
            return None

    def put(self, key: str, array: np.ndarray) -> None:
        """Store ``array`` as ``key`` (atomic, durable: see :func:`atomic_write`)."""
        atomic_write(self._path(key), lambda fh: np.save(fh, np.asarray(array)))

    def has(self, key: str) -> bool:
        """Whether ``key`` is stored."""
        return self._path(key).exists()


class Store:
    INFO_CACHE = 64  # stored domains are immutable: keep recent DomainInfo objects

    def __init__(self, data_dir: Path | str):
        self._infos: OrderedDict[str, DomainInfo] = OrderedDict()
        self._lock = threading.Lock()
        self.root = Path(data_dir)
        self.domain_dir = self.root / "domains"
        self.result_dir = self.root / "results"
        self.blob_dir = self.root / "blobs"
        for folder in (self.domain_dir, self.result_dir, self.blob_dir):
            folder.mkdir(parents=True, exist_ok=True)

    # -- domains --------------------------------------------------------
    @staticmethod
    def check_id(domain_id: str, field: str = "domain_id") -> str:
        if not _ID.match(domain_id or ""):
            raise NotFound(f"unknown domain {domain_id!r}", field=field)
        return domain_id

    def put_domain(self, domain: Domain, source: dict | None = None) -> tuple[dict, bool]:
        """Store ``domain``; returns ``(meta, created)`` (created False if already stored)."""
        domain_id = domain.content_hash()
        stored = None
        try:
            stored = json.loads(self._meta_path(domain_id).read_text())
        except (OSError, ValueError):
            pass  # not stored yet (or unreadable: rewritten below)
        labels = np.asarray(domain.component_labels, dtype=np.int32)
        aux = {"areas": np.asarray(domain.areas, dtype=np.float64), "component_labels": labels}
        pts = domain_points(domain)
        if pts is not None:
            aux["points"] = np.asarray(pts, dtype=np.float64)
        summary = jsonable(domain.summary())
        meta = {
            "id": domain_id,
            "kind": domain.kind,
            "parameters": jsonable(domain.parameters()),
            "summary": summary,
            "source": source or {},
            "created_at": time.time(),
        }
        # written also when stored already (the same content, replaced atomically): an
        # upload then takes as long whether or not another tenant holds the domain
        _write_npz(self.domain_dir / f"{domain_id}.npz", domain.to_arrays())
        _write_npz(self.domain_dir / f"{domain_id}.aux.npz", aux)
        _write_json(self._meta_path(domain_id), stored or meta)
        return stored or meta, stored is None

    # -- domains released by a tenant, removed by the background sweep if nobody holds them
    @property
    def _released_dir(self) -> Path:
        return self.domain_dir / ".released"

    def mark_released(self, domain_id: str) -> None:
        """Note that a holding of the domain was dropped (``released_domains``)."""
        self.check_id(domain_id)
        self._released_dir.mkdir(exist_ok=True)
        (self._released_dir / domain_id).touch()

    def released_domains(self) -> list[str]:
        try:
            return sorted(p.name for p in self._released_dir.iterdir() if _ID.match(p.name))
        except FileNotFoundError:
            return []

    def clear_released(self, domain_id: str) -> None:
        (self._released_dir / domain_id).unlink(missing_ok=True)

    def _meta_path(self, domain_id: str) -> Path:
        return self.domain_dir / f"{domain_id}.json"

    def get_domain_meta(self, domain_id: str) -> dict:
        self.check_id(domain_id)
        try:
            return json.loads(self._meta_path(domain_id).read_text())
        except FileNotFoundError:
            raise NotFound(f"unknown domain {domain_id!r}", field="domain_id") from None

    def domain_info(self, domain_id: str) -> DomainInfo:
        """Validation view of a stored domain (cached; a deleted domain is never returned)."""
        self.check_id(domain_id)
        with self._lock:
            info = self._infos.get(domain_id)
        if info is not None and self._meta_path(domain_id).exists():
            with self._lock:
                self._infos.move_to_end(domain_id)
            return info
        info = DomainInfo(domain_id, self.get_domain_meta(domain_id), self)
        with self._lock:
            self._infos[domain_id] = info
            while len(self._infos) > self.INFO_CACHE:
                self._infos.popitem(last=False)
        return info

    def _load_npz(self, path: Path, domain_id: str) -> dict[str, np.ndarray]:
        try:
            return _read_npz(path)
        except FileNotFoundError:
            raise NotFound(f"unknown domain {domain_id!r}", field="domain_id") from None

    def domain_arrays(self, domain_id: str) -> dict[str, np.ndarray]:
        self.check_id(domain_id)
        return self._load_npz(self.domain_dir / f"{domain_id}.npz", domain_id)

    def load_domain(self, domain_id: str) -> Domain:
        """Rebuild the domain object (operators are built lazily by the domain)."""
        meta = self.get_domain_meta(domain_id)
        domain = domain_from_arrays(meta["kind"], self.domain_arrays(domain_id),
                                    meta.get("parameters") or {})
        domain.artifacts = self.domain_artifacts(domain_id)
        return domain

    def domain_artifacts(self, domain_id: str) -> DomainArtifacts:
        """The stored domain's artifacts (all-pairs geodesics): shared by every process."""
        return DomainArtifacts(self.domain_dir / "artifacts" / self.check_id(domain_id))

    def list_domains(self) -> list[dict]:
        out = []
        for path in sorted(self.domain_dir.glob("*.json")):
            try:
                out.append(json.loads(path.read_text()))
            except (OSError, ValueError):
                continue  # deleted or being replaced concurrently
        out.sort(key=lambda m: m.get("created_at", 0))
        return out

    def domain_bytes(self, domain_id: str) -> int:
        """Bytes the stored domain takes (its arrays, validation arrays and metadata)."""
        total = 0
        for suffix in (".npz", ".aux.npz", ".json"):
            try:
                total += (self.domain_dir / f"{domain_id}{suffix}").stat().st_size
            except FileNotFoundError:
                pass
        return total

    # the domain's files, metadata first: it marks the domain complete, so it goes first and
    # comes back last
    DOMAIN_SUFFIXES = (".json", ".aux.npz", ".npz")

    def has_domain(self, domain_id: str) -> bool:
        return self._meta_path(domain_id).exists()

    def retire_domain(self, domain_id: str) -> Path | None:
        """Move the domain's files into a folder of their own (it disappears at once;
        processes that already opened or cached it keep working on their copy); returns the
        folder, for ``restore_domain`` or ``purge_retired``, or None if the domain is not
        stored."""
        self.check_id(domain_id)
        with self._lock:
            self._infos.pop(domain_id, None)
        folder = self.domain_dir / f".retired-{domain_id}-{os.urandom(8).hex()}"
        folder.mkdir()
        moved = []
        for suffix in self.DOMAIN_SUFFIXES:
            try:
                os.replace(self.domain_dir / f"{domain_id}{suffix}", folder / suffix[1:])
                moved.append(suffix)
            except FileNotFoundError:
                pass
        if ".json" not in moved:  # not stored (or removed meanwhile)
            self.purge_retired(folder)
            return None
        try:
            os.replace(self.domain_artifacts(domain_id).folder, folder / "artifacts")
        except FileNotFoundError:
            pass
        return folder

    def restore_domain(self, domain_id: str, folder: Path) -> None:
        """Put retired files back (metadata last); a file stored again meanwhile has the same
        content (content addressing) and is simply replaced."""
        try:
            os.replace(folder / "artifacts", self.domain_artifacts(domain_id).folder)
        except OSError:
            pass  # none, or computed again meanwhile (the same content)
        for suffix in reversed(self.DOMAIN_SUFFIXES):
            try:
                os.replace(folder / suffix[1:], self.domain_dir / f"{domain_id}{suffix}")
            except FileNotFoundError:
                pass
        self.purge_retired(folder)

    @staticmethod
    def purge_retired(folder: Path) -> None:
        shutil.rmtree(folder, ignore_errors=True)

    # -- results --------------------------------------------------------
    def put_result(self, job_id: str, payload: dict, arrays: dict[str, np.ndarray],
                   files: dict | None = None, durable: bool = False) -> str:
        """Store a job's result (arrays and files first, JSON last); returns its location.

        ``files``: ``name -> ResultFile(media_type, data)``, listed in the payload's
        ``files`` as ``{name: {"media_type", "bytes"}}``. Not fsynced by default: the job
        table (SQLite WAL, synchronous=NORMAL) gives the same guarantee — atomic across
        process crashes — and a result can be recomputed.
        """
        if arrays:
            _write_npz(self.result_dir / f"{job_id}.npz", arrays, durable)
        listed = {}
        if files:
            folder = self.result_dir / f"{job_id}.files"
            folder.mkdir(exist_ok=True)
            for name, item in files.items():
                if not _FILE_NAME.match(name):
                    raise ValueError(f"invalid result file name {name!r}")
                atomic_write(folder / name, lambda fh, d=item.data: fh.write(d), durable)
                listed[name] = {"media_type": item.media_type, "bytes": len(item.data)}
        payload = {**payload, "files": listed}
        _write_json(self.result_dir / f"{job_id}.json", jsonable(payload), durable)
        return f"results/{job_id}.json"

    @staticmethod
    def row_result(payload: dict, arrays: dict[str, np.ndarray], files: dict | None
                   ) -> dict | None:
        """The result document to keep in the job row instead of ``put_result``'s files:
        a payload without arrays or files whose JSON has at most ``ROW_RESULT_BYTES``
        (None otherwise). It is then committed with the job's final state, in one write."""
        if arrays or files:
            return None
        doc = jsonable({**payload, "files": {}})
        return doc if len(json.dumps(doc)) <= ROW_RESULT_BYTES else None

    def get_result_file(self, job_id: str, name: str, payload: dict | None = None
                        ) -> tuple[bytes, str]:
        """``(data, media_type)`` of a file a job produced; 404 naming ``name`` otherwise.
        ``payload``: the job's result document when the caller has it (``row_result``)."""
        listed = (payload if payload is not None else self.get_result(job_id)).get("files") or {}
        if name not in listed or not _FILE_NAME.match(name):
            raise NotFound(f"job {job_id} has no file {name!r}", field="name")
        try:
            data = (self.result_dir / f"{job_id}.files" / name).read_bytes()
        except FileNotFoundError:
            raise NotFound(f"job {job_id} has no file {name!r}", field="name") from None
        return data, listed[name]["media_type"]

    def result_array_index(self, job_id: str) -> dict[str, StoredArray]:
        """Every stored array of a job (shape, dtype, file size), without reading the data."""
        path = self.result_dir / f"{job_id}.npz"
        try:
            return _npz_index(path)
        except FileNotFoundError:
            return {}

    def _stored_array(self, job_id: str, name: str) -> StoredArray:
        found = self.result_array_index(job_id).get(name)
        if found is None:
            raise NotFound(f"job {job_id} has no array {name!r}", field="name")
        return found

    def result_array_npy(self, job_id: str, name: str, chunk: int = 1 << 20
                         ) -> tuple[Iterator[bytes], int]:
        """``(chunks, size)``: the array's .npy file, read from the archive as it is sent."""
        stored = self._stored_array(job_id, name)
        path = self.result_dir / f"{job_id}.npz"
        archive = zipfile.ZipFile(path)  # opened now: a 404 above, not in the middle of a body

        def chunks() -> Iterator[bytes]:
            with archive, archive.open(f"{name}.npy") as member:
                while data := member.read(chunk):
                    yield data

        return chunks(), stored.npy_bytes

    def get_result_row(self, job_id: str, name: str, row: int) -> np.ndarray:
        """Row ``row`` of a stored 2-D array (``StoredArray.shape`` checked by the caller);
        only that row's bytes are read when the archive stores the array plainly."""
        stored = self._stored_array(job_id, name)
        if stored.data_offset is None or len(stored.shape) != 2:
            return self.get_result_array(job_id, name)[row]
        width = stored.shape[1] * stored.dtype.itemsize
        with open(self.result_dir / f"{job_id}.npz", "rb") as fh:
            fh.seek(stored.data_offset + row * width)
            data = fh.read(width)
        return np.frombuffer(data, dtype=stored.dtype).astype(stored.dtype.newbyteorder("="))

    def get_result_array(self, job_id: str, name: str) -> np.ndarray:
        """One stored result array (only that member of the archive is read)."""
        path = self.result_dir / f"{job_id}.npz"
        try:
            with np.load(path, allow_pickle=False) as archive:
                if name not in archive.files:
                    raise NotFound(f"job {job_id} has no array {name!r}", field="name")
                return archive[name]
        except FileNotFoundError:
            raise NotFound(f"job {job_id} has no array {name!r}", field="name") from None

    # -- blobs (uploaded inputs other than domains, e.g. images) -----------------
    def put_blob(self, data: bytes, media_type: str, meta: dict | None = None
                 ) -> tuple[dict, bool]:
        """Store ``data`` under its SHA-256; returns ``(meta, created)``."""
        import hashlib

        blob_id = hashlib.sha256(data).hexdigest()
        meta_path = self.blob_dir / f"{blob_id}.json"
        if meta_path.exists():
            try:
                return json.loads(meta_path.read_text()), False
            except (OSError, ValueError):
                pass
        info = {"id": blob_id, "media_type": media_type, "bytes": len(data),
                "created_at": time.time(), **(meta or {})}
        atomic_write(self.blob_dir / f"{blob_id}.bin", lambda fh: fh.write(data))
        _write_json(meta_path, jsonable(info))
        return info, True

    def blob_meta(self, blob_id: str, field: str = "blob_id") -> dict:
        if not _ID.match(blob_id or ""):
            raise NotFound(f"unknown blob {blob_id!r}", field=field)
        try:
            return json.loads((self.blob_dir / f"{blob_id}.json").read_text())
        except FileNotFoundError:
            raise NotFound(f"unknown blob {blob_id!r}", field=field) from None

    def get_blob(self, blob_id: str, field: str = "blob_id") -> bytes:
        self.blob_meta(blob_id, field)
        try:
            return (self.blob_dir / f"{blob_id}.bin").read_bytes()
        except FileNotFoundError:
            raise NotFound(f"unknown blob {blob_id!r}", field=field) from None

    def get_result(self, job_id: str) -> dict:
        try:
            return json.loads((self.result_dir / f"{job_id}.json").read_text())
        except FileNotFoundError:
            raise NotFound(f"no result stored for job {job_id!r}", field="job_id") from None

    # -- completion markers (cheap to poll; the job table stays the source of truth) ----
    def mark_done(self, job_id: str) -> None:
        """Touch ``results/<job>.done`` once the job's final state is committed."""
        try:
            (self.result_dir / f"{job_id}.done").touch()
        except OSError:
            pass  # only an optimization for waiting clients

    def is_done(self, job_id: str) -> bool:
        return (self.result_dir / f"{job_id}.done").exists()

    def prune_done_markers(self, older_than: float) -> int:
        cutoff, removed = time.time() - older_than, 0
        for path in self.result_dir.glob("*.done"):
            try:
                if path.stat().st_mtime < cutoff:
                    path.unlink()
                    removed += 1
            except OSError:
                continue
        return removed

    def get_result_arrays(self, job_id: str) -> dict[str, np.ndarray]:
        path = self.result_dir / f"{job_id}.npz"
        if not path.exists():
            return {}
        return _read_npz(path)

