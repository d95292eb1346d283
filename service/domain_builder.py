"""Building large domains in a memory-bounded child process, so the API's memory stays small.

A domain's construction (k-nearest-neighbour graphs, Laplacians, component labels, a mesh
file's parsing and welding) can take many times the upload's size: a 1.9-million-point cloud
once raised the API process to 15 GiB, a 3 MB point cloud to 1.3 GB. Every build is
estimated first, from a JSON domain's sizes or a mesh file's declared counts
(service.mesh_sizes); one above ``OTGEO_JOB_MEMORY_BYTES`` is refused (413), one above
``IN_PROCESS_BUILD_BYTES`` is built and stored by a child process whose address space is
capped (``RLIMIT_AS`` at :func:`builder_memory_limit`), and the API only receives the stored
domain's metadata. A build that runs out of that bound answers 413 naming the upload's size
field. Small builds run in the calling thread (no process hop). A child left holding more
than ``RECYCLE_RSS_BYTES`` after a build is replaced, so it does not stay large. The
builds themselves (:func:`build_domain`, :func:`build_mesh_file`) live here, below
:mod:`service.domains`, which calls them in process.
"""

from __future__ import annotations

import asyncio
import logging
from concurrent.futures.process import BrokenProcessPool

from service.child_pool import ChildPool, die_with_parent
from service.errors import ApiError, PayloadTooLarge
from service.limits import WORKER_BASE_BYTES
from service.schemas import check_point_limit
from solvers.domains import load_mesh

log = logging.getLogger("otgeo.service")

# builds estimated up to this run in the API process (a few thousand points, ~20k vertices):
# four at once keep the API well under 600 MB (bench/upload_memory.py)
IN_PROCESS_BUILD_BYTES = 32 * 2**20
# a mesh file whose header tells nothing (service.mesh_sizes) is built here only when tiny
IN_PROCESS_UNKNOWN_FILE_BYTES = 256 * 2**10
# a builder child resident above this after a build is replaced by a fresh one (its idle
# size with the mesh libraries loaded is about 250 MB)
RECYCLE_RSS_BYTES = 320 * 2**20


# Bytes a JSON domain's build needs per unit of its size (bench/domain_build_memory.py,
# measured peaks rounded up): a point cloud's per point and neighbor (k-NN graph, local
# triangulations, Laplacian), a graph's per node and per edge, a mesh's per vertex and per
# face, a grid's per cell.
BUILD_BYTES = {"pointcloud_neighbor": 400, "graph_node": 32, "graph_edge": 32,
               "mesh_vertex": 800, "mesh_face": 400, "grid_cell": 16,
               # a mesh file's (parse, weld, robust Laplacian): 1.70-1.72 kB per vertex
               # measured for 90k and 360k vertices (OBJ, PLY), with two faces per vertex
               "file_vertex": 1000, "file_face": 400}


def estimate_build_bytes(spec) -> int:
    """Working memory of building a validated JSON domain spec, from its sizes alone."""
    return spec.build_bytes(BUILD_BYTES)


def estimate_file_build_bytes(vertices: int, faces: int) -> int:
    """Working memory of building a mesh file of these declared counts."""
    return BUILD_BYTES["file_vertex"] * vertices + BUILD_BYTES["file_face"] * faces


def check_build_memory(settings, spec, field: str) -> None:
    """413 naming ``field`` (the spec's size field) when building ``spec`` would need more
    than ``OTGEO_JOB_MEMORY_BYTES``: refused at submission, before any build starts."""
    check_memory_need(settings, estimate_build_bytes(spec), field)


def check_memory_need(settings, need: int, field: str) -> None:
    """413 naming ``field`` when a build's estimate ``need`` exceeds the job memory bound."""
    limit = int(settings.job_memory_bytes)
    if need > limit:
        raise PayloadTooLarge(f"building this domain would need about {need / 2**30:.3g} GiB "
                              f"of working memory, more than the limit of {limit / 2**30:.3g} "
                              "GiB (OTGEO_JOB_MEMORY_BYTES): upload fewer points",
                              field=field)


def builder_memory_limit(settings) -> int:
    """Address space of the builder process: interpreter base + one job's working memory."""
    return WORKER_BASE_BYTES + int(settings.job_memory_bytes)


def _init_child(limit: int) -> None:
    """Builder initializer: cap the address space, die with the API process (Linux)."""
    import resource

    die_with_parent()
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    if soft == resource.RLIM_INFINITY or soft > limit:
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))


def _resident_bytes() -> int:
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def build_domain(settings, spec, source: dict):
    """The domain of a validated JSON spec (sizes checked against ``max_vertices`` first)."""
    return spec.build(settings.max_vertices)


def build_mesh_file(settings, data: bytes, ext: str, laplacian: str, weld, source: dict):
    """The mesh of an uploaded file (``file_arguments``), at most ``max_vertices``."""
    mesh = load_mesh(data, file_type=ext, laplacian=laplacian, weld=weld)
    check_point_limit(mesh.n, settings.max_vertices, "file")
    return mesh


def _build_store_measure(settings, method: str, args: tuple) -> tuple[tuple, int]:
    """In the child: ``_build_and_store``'s answer and the child's resident bytes after it
    (the domain freed)."""
    out = _build_and_store(settings, method, args)
    return out, _resident_bytes()


def _build_and_store(settings, method: str, args: tuple) -> tuple:
    """In the child: ``("ok", meta, created)`` or ``("error", status, code, message, field)``
    (``"memory"`` when the bound was hit)."""
    from service.errors import from_library
    from service.store import Store
    from solvers.errors import OTGeoError

    try:
        domain = (build_domain if method == "spec" else build_mesh_file)(settings, *args)
        meta, created = Store(settings.data_dir).put_domain(domain, args[-1])
        return ("ok", meta, created)
    except MemoryError:
        return ("memory",)
    except (ApiError, OTGeoError) as exc:  # reported to the client as in the API process
        err = from_library(exc) if isinstance(exc, OTGeoError) else exc
        return ("error", err.status_code, err.code, err.message, err.field)
    except Exception:
        log.exception("domain build failed")
        return ("internal",)


BUILDER = ChildPool(_init_child)


def _too_large(settings, field: str) -> PayloadTooLarge:
    limit = builder_memory_limit(settings)
    return PayloadTooLarge(f"building this domain needs more than the {limit / 2**30:.3g} GiB "
                           "a domain build may use (OTGEO_JOB_MEMORY_BYTES plus the "
                           "interpreter): upload fewer points", field=field)


async def build_in_child(settings, method: str, args: tuple, field: str) -> tuple[dict, bool]:
    """``(meta, created)`` of the domain built and stored by the bounded child process;
    ``method`` is ``"spec"`` (args: spec, source) or ``"file"`` (args: data, filename, ext,
    laplacian, weld, source)."""
    limit = builder_memory_limit(settings)
    try:
        out, resident = await asyncio.wrap_future(
            BUILDER.get(limit).submit(_build_store_measure, settings, method, args))
    except BrokenProcessPool as exc:  # killed by the bound (an allocation that aborted)
        log.warning("domain builder process died (%s)", exc)
        BUILDER.discard()
        raise _too_large(settings, field) from exc
    if resident > RECYCLE_RSS_BYTES:  # a fresh child for the next build; queued ones finish
        BUILDER.retire()
    if out[0] == "memory":
        BUILDER.discard()  # a fresh child: the failed build's fragments go with the old one
        raise _too_large(settings, field)
    if out[0] == "internal":  # logged by the child; the app's handler answers 500
        raise RuntimeError("domain build failed in the builder process")
    if out[0] == "error":
        _, status, code, message, err_field = out
        err = ApiError(message, field=err_field, code=code)
        err.status_code = status
        raise err
    return out[1], out[2]


def shutdown() -> None:
    BUILDER.discard()
