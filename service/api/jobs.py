"""/v1/jobs: state, result (JSON / GLB), server-sent progress events, cancel."""

from __future__ import annotations

import asyncio
import json
from typing import Annotated, Literal, Union
from urllib.parse import quote

from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, StreamingResponse
from pydantic import BaseModel, Field, create_model

from service.api.deps import JobSvc
from service.api.paging import Cursor, decode_cursor, encode_cursor
from service.errors import ErrorResponse, responses
from service.export import NPY_MEDIA_TYPE
from service.jobs.db import TERMINAL
from service.schemas import ArrayRow, JobList, JobOut, JobResult, JobState

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

EVENT_POLL = 0.2  # seconds between job-table reads of an event stream
EVENT_KEEPALIVE = 15.0


@router.get("", operation_id="listJobs", response_model=JobList, responses=responses(401, 422))
def list_jobs(svc: JobSvc,
              limit: Annotated[int, Query(ge=1, le=1000, description="page size")] = 100,
              state: Annotated[JobState | None,
                               Query(description="only jobs in this state")] = None,
              operation: Annotated[str | None, Query(
                  description="only jobs of this operation (e.g. barycenters)")] = None,
              domain_id: Annotated[str | None, Query(
                  description="only jobs on this domain")] = None,
              cursor: Cursor = None):
    """Jobs, newest first, a page at a time (follow `next_cursor` until it is null)."""
    rows = svc.list(limit + 1, state, after=decode_cursor(cursor), operation=operation,
                    domain_id=domain_id)
    page = rows[:limit]
    for row in page:
        _with_position(svc, row)
    more = len(rows) > limit
    return JobList(jobs=[JobOut.from_row(j, svc.rt.operations) for j in page],
                   next_cursor=encode_cursor(page[-1].created_at, page[-1].id) if more else None)


def _with_position(svc, job):
    """Attach the queue position of a queued job (read by JobOut.from_row)."""
    if job.state == "queued":
        job.queue_position = svc.rt.repo.queue_position(job)
    return job


@router.get("/{job_id}", operation_id="getJob", response_model=JobOut,
            responses=responses(401, 404))
def get_job(job_id: str, svc: JobSvc):
    """State, progress (iteration, residual, fraction done, estimated seconds left) and,
    while queued, the position in its queue."""
    # with its queue position (JobService.get)
    return JobOut.from_row(svc.get(job_id), svc.rt.operations)


@router.delete("/{job_id}", operation_id="cancelJob", response_model=JobOut,
               summary="Cancel a job: a queued one at once, a running one between two solver "
               "iterations; the job remains (it is not deleted)",
               responses={200: {"description": "the job, cancelled (a queued one) or with "
                                "`cancel_requested` set (a running one); it stays readable "
                                "at GET /v1/jobs/{job_id}"},
                          409: {"model": ErrorResponse, "description": "job already finished"},
                          **responses(401, 404)})
def cancel_job(job_id: str, svc: JobSvc):
    """Cancel: a queued job at once, a running one between two solver iterations. This does
    not delete the job: it stays listed and readable, in state `cancelled` once stopped (the
    partial progress kept), so a client can still follow it."""
    return JobOut.from_row(svc.cancel(job_id), svc.rt.operations)


def result_models(operations) -> list[type[BaseModel]]:
    """One result model per operation (``operation`` a constant, ``values`` the operation's
    ``result_model``), then the generic JobResult: what ``getJobResult`` may return, so a
    generated SDK parses each result into its operation's type."""
    models = []
    for op in operations.values():
        base = op.operation_id[len("create"):] if op.operation_id.startswith("create") \
            else op.operation_id[:1].upper() + op.operation_id[1:]
        values = op.result_model or dict
        models.append(create_model(
            f"{base}Result", __base__=JobResult,
            __doc__=f"Result of a `{op.name}` job.",
            operation=(Literal[op.name], Field(description="the operation")),
            values=(values, Field(description=f"values of the {op.name} result"))))
    return [*models, JobResult]


def build_result_router(operations) -> APIRouter:
    """``GET /v1/jobs/{job_id}/result`` typed by the app's operation registry."""
    results = APIRouter(prefix="/v1/jobs", tags=["jobs"])
    models = result_models(operations)
    union = models[0] if len(models) == 1 else Union[tuple(models)]  # noqa: UP007

    @results.get("/{job_id}/result", operation_id="getJobResult", response_model=union,
                 responses={409: {"model": ErrorResponse, "description": "job not "
                                  "(successfully) finished"}, **responses(401, 404)})
    def get_job_result(job_id: str, svc: JobSvc,
                       arrays: bool = Query(True, description="inline the arrays that fit "
                                            "the size budget (false: links only)")):
        """The result: `values` typed per operation (see each `...Result` schema), the files
        produced, every array as a linked .npy file (`array_files`) and, within the result's
        size budget (OTGEO_RESULT_JSON_BYTES), smallest first, also inline as nested lists
        (`arrays`). A job `failed` with code `not_converged` keeps its partial result here
        (`values.converged` is false): it is not a solution."""
        return JSONResponse(svc.result(job_id, include_arrays=arrays))

    return results


@router.get("/{job_id}/result.glb", operation_id="getJobResultGlb",
            response_class=Response,
            responses={200: {"content": {
                                 "model/gltf-binary": {
                                     "schema": {"type": "string", "format": "binary"}},
                                 "application/octet-stream": {
                                     "schema": {"type": "string", "format": "binary"}}},
                             "description": "glTF 2.0 binary of the result on its domain "
                             "(sent as model/gltf-binary)"},
                       409: {"model": ErrorResponse, "description": "job not finished, "
                             "or its operation has no glTF (code `no_glb`: a color transfer, "
                             "a BRDF interpolation; the job then has no `links.result_glb`)"},
                       **responses(401, 404, 422)})
def get_job_result_glb(job_id: str, svc: JobSvc):
    return Response(svc.result_glb(job_id), media_type="model/gltf-binary")


# Media types of the files operations produce (service.operations: ResultFile), then the
# generic binary type that SDK generators read (openapi-python-client skips the others)
FILE_MEDIA_TYPES = ("image/png", "image/jpeg", "model/gltf-binary", "application/octet-stream")


@router.get("/{job_id}/files/{name}", operation_id="getJobFile", response_class=Response,
            responses={200: {"content": {t: {"schema": {"type": "string", "format": "binary"}}
                                         for t in FILE_MEDIA_TYPES},
                             "description": "a file the job produced, sent with its media type "
                             "(PNG or JPEG image, glTF binary); listed in the result's `files`"},
                       409: {"model": ErrorResponse, "description": "job not finished"},
                       **responses(401, 404)})
def get_job_file(job_id: str, name: str, svc: JobSvc):
    data, media_type = svc.result_file(job_id, name)
    return Response(data, media_type=media_type)


BINARY = {"schema": {"type": "string", "format": "binary"}}


@router.get("/{job_id}/arrays/{name}.npy", operation_id="getJobResultArray",
            response_class=Response,
            responses={200: {"content": {NPY_MEDIA_TYPE: BINARY,
                                         "application/octet-stream": BINARY},
                             "description": "the array as a NumPy .npy file (sent as "
                             f"{NPY_MEDIA_TYPE}): a header giving dtype and shape, then the "
                             "raw little-endian values in C order; listed in the result's "
                             "`array_files`"},
                       409: {"model": ErrorResponse, "description": "job not finished"},
                       **responses(401, 404)})
def get_job_result_array(job_id: str, name: str, svc: JobSvc):
    """One result array in binary, however large (the JSON result inlines small ones only)."""
    chunks, size = svc.result_npy(job_id, name)
    return StreamingResponse(chunks, media_type=NPY_MEDIA_TYPE, headers={
        "Content-Length": str(size),
        "Content-Disposition": f'attachment; filename="{job_id}-{quote(name)}.npy"'})


@router.get("/{job_id}/arrays/{name}/rows/{row}", operation_id="getJobResultRow",
            response_model=ArrayRow,
            responses={409: {"model": ErrorResponse, "description": "job not finished"},
                       **responses(401, 404, 422)})
def get_job_result_row(job_id: str, name: str, svc: JobSvc,
                       row: Annotated[int, Path(ge=0, description="row index, below the "
                                                "array's row count (else 422)")]):
    """One row of a 2-D result array (e.g. a soft map's distribution of one source vertex)."""
    return ArrayRow(name=name, row=row, values=svc.result_row(job_id, name, row))


@router.get("/{job_id}/events", operation_id="streamJobEvents",
            response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}},
                             "description": "server-sent events: `progress` with the job "
                             "JSON on every change, `end` when it finished"},
                       **responses(401, 404)})
async def stream_job_events(job_id: str, request: Request, svc: JobSvc):
    job = await run_in_threadpool(svc.get, job_id)  # 404 before streaming starts

    async def events():
        last, idle = None, 0.0
        current = job
        while True:
            data = JobOut.from_row(current, svc.rt.operations).model_dump_json()
            if data != last:
                yield f"event: progress\nid: {current.attempts}-{current.iteration or 0}\n" \
                      f"data: {data}\n\n"
                last, idle = data, 0.0
            if current.state in TERMINAL:
                yield f"event: end\ndata: {json.dumps({'state': current.state})}\n\n"
                return
            if await request.is_disconnected():
                return
            await asyncio.sleep(EVENT_POLL)
            idle += EVENT_POLL
            if idle >= EVENT_KEEPALIVE:
                yield ": keep-alive\n\n"
                idle = 0.0
            current = await run_in_threadpool(svc.get, job_id)

    return StreamingResponse(events(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache"})
