"""Building large domains in a memory-bounded child process, so the API's memory stays small.

A domain's construction (k-nearest-neighbour graphs, Laplacians, component labels, a mesh
file's parsing and welding) can take many times the upload's size: a 1.9-million-point cloud
once raised the API process to 15 GiB. Uploads above ``IN_PROCESS_POINTS`` points (or, for
mesh files, ``IN_PROCESS_FILE_BYTES``) are built and stored by a child process whose address
space is capped (``RLIMIT_AS`` at :func:`builder_memory_limit`); the API only receives the
stored domain's metadata. A build that runs out of that bound answers 413 naming the upload's
size field. Small uploads are built in the calling thread (no process hop).
"""

from __future__ import annotations

import asyncio
import logging
import math
from concurrent.futures.process import BrokenProcessPool

from service.child_pool import ChildPool, die_with_parent
from service.errors import ApiError, PayloadTooLarge
from service.limits import WORKER_BASE_BYTES

log = logging.getLogger("otgeo.service")

IN_PROCESS_POINTS = 100_000  # domains up to this many points are built in the API process
IN_PROCESS_FILE_BYTES = 8 * 2**20  # mesh files up to this size too (~150k vertices as OBJ)


# Bytes a JSON domain's build needs per unit of its size (bench/domain_build_memory.py,
# measured peaks rounded up): a point cloud's per point and neighbor (k-NN graph, local
# triangulations, Laplacian), a graph's per node and per edge, a mesh's per vertex and per
# face, a grid's per cell.
BUILD_BYTES = {"pointcloud_neighbor": 400, "graph_node": 32, "graph_edge": 32,
               "mesh_vertex": 800, "mesh_face": 400, "grid_cell": 16}


def estimate_build_bytes(spec) -> int:
    """Working memory of building a validated JSON domain spec, from its sizes alone."""
    from service.schemas import GraphSpec, GridSpec, PointCloudSpec

    b = BUILD_BYTES
    if isinstance(spec, GridSpec):
        return b["grid_cell"] * math.prod(int(s) for s in spec.shape)
    if isinstance(spec, GraphSpec):
        return b["graph_node"] * int(spec.n_nodes) + b["graph_edge"] * len(spec.edges)
    if isinstance(spec, PointCloudSpec):
        # more neighbors than other points is refused by the build itself (422)
        neighbors = min(int(spec.n_neighbors), max(len(spec.points) - 1, 1))
        return b["pointcloud_neighbor"] * len(spec.points) * neighbors
    return b["mesh_vertex"] * len(spec.vertices) + b["mesh_face"] * len(spec.faces)


def check_build_memory(settings, spec, field: str) -> None:
    """413 naming ``field`` (the spec's size field) when building ``spec`` would need more
    than ``OTGEO_JOB_MEMORY_BYTES``: refused at submission, before any build starts."""
    need, limit = estimate_build_bytes(spec), int(settings.job_memory_bytes)
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


def _build_and_store(settings, method: str, args: tuple) -> tuple:
    """In the child: ``("ok", meta, created)`` or ``("error", status, code, message, field)``
    (``"memory"`` when the bound was hit)."""
    from service.domains import build_domain, build_mesh_file
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
        out = await asyncio.wrap_future(
            BUILDER.get(limit).submit(_build_and_store, settings, method, args))
    except BrokenProcessPool as exc:  # killed by the bound (an allocation that aborted)
        log.warning("domain builder process died (%s)", exc)
        BUILDER.discard()
        raise _too_large(settings, field) from exc
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
