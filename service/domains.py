"""Domain uploads: parse, enforce limits, build, store (content addressed).

Sizes are checked against ``max_vertices`` before anything is allocated (grid sizes as
Python integers, so a shape whose product wraps int64 cannot slip through), and every
array goes through the library's own validators (``solvers.validation``), so a hostile
upload gets a 4xx naming its field, never a server error.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from service.domain_builder import (
    IN_PROCESS_BUILD_BYTES,
    IN_PROCESS_UNKNOWN_FILE_BYTES,
    build_domain,
    build_in_child,
    build_mesh_file,
    check_build_memory,
    check_memory_need,
    estimate_build_bytes,
    estimate_file_build_bytes,
)
from service.errors import InvalidInput, NotFound, PayloadTooLarge
from service.mesh_sizes import mesh_file_counts
from service.schemas import check_point_limit
from service.tenants import ANONYMOUS, QuotaExceeded, Tenant, check_bytes_quota
from solvers.domains import MESH_FORMATS

if TYPE_CHECKING:  # the runtime calls this module (its sweep), not the reverse
    from service.runtime import Runtime

WELD_VALUES = {"true": True, "1": True, "yes": True, "false": False, "0": False, "no": False,
               "auto": None, "": None}


def parse_weld(value) -> bool | None:
    """The ``weld`` form field of a mesh upload: true/false, or auto (the format's default:
    PLY/OFF/STL/glTF welded by position, OBJ by its position indices)."""
    if value is None or isinstance(value, bool):
        return value
    key = str(value).strip().lower()
    if key not in WELD_VALUES:
        raise InvalidInput(f"weld must be true, false or auto, got {str(value)[:20]!r}",
                           field="weld")
    return WELD_VALUES[key]


class DomainService:
    """Domains as one tenant sees them. Stored data is content-addressed and shared; a tenant
    sees the domains it holds (service.jobs.tenancy), with its own upload record, and an admin
    every stored domain. Another tenant's domain is "unknown" (404), so ids do not leak."""

    def __init__(self, runtime: Runtime, tenant: Tenant = ANONYMOUS):
        self.rt = runtime
        self.settings = runtime.settings
        self.tenant = tenant

    def _check_points(self, n: int, field: str) -> None:
        _check_points(self.settings, n, field)

    def from_file(self, data: bytes, filename: str | None, file_type: str | None,
                  laplacian: str = "robust", weld: bool | str | None = None
                  ) -> tuple[dict, bool]:
        """Store an uploaded mesh file, built in this process. ``weld``: merge vertices at
        equal positions (seams); None/"auto": the format's default (see
        ``solvers.domains.mesh``)."""
        args = file_arguments(data, filename, file_type, laplacian, weld)
        return self._put(build_mesh_file(self.settings, *args), args[-1])

    def from_spec(self, spec) -> tuple[dict, bool]:
        """Store a JSON domain, built in this process."""
        source = {"format": "json"}
        check_build_memory(self.settings, spec, spec_size(spec)[0])
        return self._put(build_domain(self.settings, spec, source), source)

    async def create_from_file(self, data: bytes, filename: str | None, file_type: str | None,
                               laplacian: str = "robust", weld: bool | str | None = None
                               ) -> tuple[dict, bool]:
        """As :meth:`from_file`, sized first from the file's declared counts: 413 beyond
        ``max_vertices`` or the job memory bound, and a build estimated above
        ``IN_PROCESS_BUILD_BYTES`` runs in the bounded builder process."""
        from fastapi.concurrency import run_in_threadpool

        args = file_arguments(data, filename, file_type, laplacian, weld)
        counts = (mesh_file_counts(data, args[1]) if len(data) < 2**20 else  # an OBJ: scanned
                  await run_in_threadpool(mesh_file_counts, data, args[1]))
        if counts is None:
            here = len(data) <= IN_PROCESS_UNKNOWN_FILE_BYTES
        else:
            vertices, faces = counts
            if vertices > self.settings.max_vertices:
                raise PayloadTooLarge(f"the file declares {vertices} vertices, more than the "
                                      f"limit of {self.settings.max_vertices}", field="file")
            need = estimate_file_build_bytes(vertices, faces)
            check_memory_need(self.settings, need, "file")
            here = need <= IN_PROCESS_BUILD_BYTES
        if here:
            return await run_in_threadpool(self.from_file, data, filename, file_type,
                                           laplacian, weld)
        meta, created = await build_in_child(self.settings, "file", args, "file")
        return self._stored(meta, created, args[-1])

    async def create_from_spec(self, spec) -> tuple[dict, bool]:
        """As :meth:`from_spec`; a domain whose build is estimated above
        ``IN_PROCESS_BUILD_BYTES`` is built in the bounded builder process."""
        from fastapi.concurrency import run_in_threadpool

        field, n = spec_size(spec)
        self._check_points(n, field)
        check_build_memory(self.settings, spec, field)  # 413 before any build
        if estimate_build_bytes(spec) <= IN_PROCESS_BUILD_BYTES:
            return await run_in_threadpool(self.from_spec, spec)
        source = {"format": "json"}
        meta, created = await build_in_child(self.settings, "spec", (spec, source), field)
        return self._stored(meta, created, source)

    def _put(self, domain, source: dict) -> tuple[dict, bool]:
        meta, stored_now = self.rt.store.put_domain(domain, source)
        return self._stored(meta, stored_now, source,
                            restore=lambda: self.rt.store.put_domain(domain, source))

    def _stored(self, meta: dict, stored_now: bool, source: dict, restore=None
                ) -> tuple[dict, bool]:
        """Record the caller's holding of a stored domain (stored once, whoever uploads it).
        ``created``: new to the caller (an admin: new to the store). ``restore`` stores the
        domain again if the last other holder deleted it meanwhile (a domain built in the
        builder process has none: that race then leaves the caller's entry without data,
        and its next upload stores it again)."""
        store, tenancy = self.rt.store, self.rt.tenancy
        domain_id = meta["id"]
        held = tenancy.holding(self.tenant.id, "domain", domain_id)
        if held is None:
            size = store.domain_bytes(domain_id)
            try:
                check_bytes_quota(self.settings, self.tenant,
                                  tenancy.stored_bytes(self.tenant.id), size)
            except QuotaExceeded:
                if stored_now:
                    self._drop_if_unheld(domain_id)
                raise
            held = tenancy.hold(self.tenant.id, "domain", domain_id, size, source)
            if not store.has_domain(domain_id) and restore is not None:
                restore()
            created = True
        else:
            created = False
        if self.tenant.admin:
            created = stored_now
        else:
            meta = _as_held(meta, held)
        if not created:  # say so, and from which upload the stored domain came
            meta = {**meta, "already_existed": True, "upload": source}
        return meta, created

    # -- what the tenant sees ---------------------------------------------------
    def holds(self, kind: str, object_id: str) -> bool:
        """Whether the tenant may see and use a stored object (an admin: every one)."""
        return self.tenant.admin or \
            self.rt.tenancy.holding(self.tenant.id, kind, object_id) is not None

    def _holding(self, domain_id: str, field: str = "domain_id"):
        """The tenant's holding of the domain (None for an admin); 404 when it has none."""
        self.rt.store.check_id(domain_id, field)
        if self.tenant.admin:
            return None
        held = self.rt.tenancy.holding(self.tenant.id, "domain", domain_id)
        if held is None:
            raise NotFound(f"unknown domain {domain_id!r}", field=field)
        return held

    def info(self, domain_id: str, field: str = "domain_id"):
        """The stored domain's validation view (``Store.domain_info``), if the tenant holds it."""
        self._holding(domain_id, field)
        return self.rt.store.domain_info(domain_id)

    def get(self, domain_id: str) -> dict:
        held = self._holding(domain_id)
        meta = self.rt.store.get_domain_meta(domain_id)
        return meta if held is None else _as_held(meta, held)

    def list(self) -> list[dict]:
        if self.tenant.admin:
            return self.rt.store.list_domains()
        out = []
        for held in self.rt.tenancy.holdings(self.tenant.id, "domain"):
            try:
                out.append(_as_held(self.rt.store.get_domain_meta(held.object_id), held))
            except NotFound:
                continue  # removed meanwhile
        out.sort(key=lambda m: m.get("created_at", 0))
        return out

    def delete(self, domain_id: str) -> None:
        """Drop the caller's holding; the stored domain goes with the last holding. An admin
        deletes the domain for every tenant."""
        self._holding(domain_id)
        if self.tenant.admin:
            released = self.rt.tenancy.release(None, "domain", domain_id)
            if not self._drop_if_unheld(domain_id) and not released:
                raise NotFound(f"unknown domain {domain_id!r}", field="domain_id")
            return
        # the same work whether or not another tenant holds the domain (the time taken told
        # which): the files go, if nobody holds them, at the next background sweep
        self.rt.tenancy.release(self.tenant.id, "domain", domain_id)
        self.rt.store.mark_released(domain_id)

    def _drop_if_unheld(self, domain_id: str) -> bool:
        return drop_if_unheld(self.rt, domain_id)


def drop_if_unheld(rt, domain_id: str) -> bool:
    """Remove the stored domain if no tenant holds it; True if removed.

    Safe against a concurrent upload of the same content: the files are moved aside, then
    the holdings counted again; an upload that took a holding meanwhile gets them back
    (and one that looked after the move stores the domain again, see ``DomainService._put``)."""
    tenancy, store = rt.tenancy, rt.store
    if tenancy.holders("domain", domain_id):
        return False
    folder = store.retire_domain(domain_id)
    if folder is None:
        return False
    if tenancy.holders("domain", domain_id):
        store.restore_domain(domain_id, folder)
        return False
    store.purge_retired(folder)
    rt.cache.discard(("domain", domain_id))
    return True


def sweep_released_domains(rt) -> list[str]:
    """Remove the domains tenants released (``DomainService.delete``) that nobody holds now;
    returns their ids. Run by the reaper's loop, off the request path."""
    removed = []
    for domain_id in rt.store.released_domains():
        rt.store.clear_released(domain_id)  # first: a release meanwhile marks it again
        if drop_if_unheld(rt, domain_id):
            removed.append(domain_id)
    return removed


def _as_held(meta: dict, held) -> dict:
    """A stored domain's metadata as its holder sees it: its own upload and time."""
    return {**meta, "source": held.source or {}, "created_at": held.created_at}


def _check_points(settings, n: int, field: str) -> None:
    check_point_limit(n, settings.max_vertices, field)


def spec_size(spec) -> tuple[str, int]:
    """``(field, points)`` of a JSON domain before it is built (Python ints)."""
    return spec.size_field, spec.n_points()


def file_arguments(data: bytes, filename: str | None, file_type: str | None, laplacian: str,
                   weld) -> tuple:
    """``(data, ext, laplacian, weld, source)`` of a mesh file upload, checked."""
    if not data:
        raise InvalidInput("the uploaded file is empty", field="file")
    ext = (file_type or os.path.splitext(filename or "")[1]).lower().lstrip(".")
    if not ext:
        raise InvalidInput("cannot tell the mesh format: give a file name with an extension "
                           f"or a 'format' field ({', '.join(MESH_FORMATS)})", field="format")
    if ext not in MESH_FORMATS:
        raise InvalidInput(f"unsupported mesh format {ext[:20]!r}; expected one of "
                           f"{', '.join(MESH_FORMATS)}", field="format")
    if laplacian not in ("robust", "cotan"):
        raise InvalidInput("laplacian must be 'robust' or 'cotan'", field="laplacian")
    weld = parse_weld(weld)
    source = {"filename": filename, "format": ext, "bytes": len(data)}
    if weld is not None:
        source["weld"] = weld
    return data, ext, laplacian, weld, source
