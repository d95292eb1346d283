"""/v1/jobs: state, result (JSON / GLB), server-sent progress events, cancel."""

from __future__ import annotations

import asyncio
import json
from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from service.api.deps import JobSvc
from service.errors import ErrorResponse, responses
from service.jobs.db import TERMINAL
from service.schemas import ArrayRow, JobList, JobOut, JobResult, JobState

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

EVENT_POLL = 0.2  # seconds between job-table reads of an event stream
EVENT_KEEPALIVE = 15.0


@router.get("", operation_id="listJobs", response_model=JobList, responses=responses(401, 422))
def list_jobs(svc: JobSvc, limit: Annotated[int, Query(ge=1, le=1000)] = 100,
              state: Annotated[JobState | None,
                               Query(description="only jobs in this state")] = None):
    return JobList(jobs=[JobOut.from_row(j) for j in svc.list(limit, state)])


@router.get("/{job_id}", operation_id="getJob", response_model=JobOut,
            responses=responses(401, 404))
def get_job(job_id: str, svc: JobSvc):
    return JobOut.from_row(svc.get(job_id))


@router.delete("/{job_id}", operation_id="cancelJob", response_model=JobOut,
               responses={409: {"model": ErrorResponse, "description": "job already finished"},
                          **responses(401, 404)})
def cancel_job(job_id: str, svc: JobSvc):
    """Cancel: a queued job at once, a running one between two solver iterations."""
    return JobOut.from_row(svc.cancel(job_id))


@router.get("/{job_id}/result", operation_id="getJobResult", response_model=JobResult,
            responses={409: {"model": ErrorResponse, "description": "job not (successfully) "
                             "finished"}, **responses(401, 404)})
def get_job_result(job_id: str, svc: JobSvc,
                   arrays: bool = Query(True, description="include result arrays")):
    return svc.result(job_id, include_arrays=arrays)


@router.get("/{job_id}/result.glb", operation_id="getJobResultGlb",
            response_class=Response,
            responses={200: {"content": {"model/gltf-binary": {
                                 "schema": {"type": "string", "format": "binary"}}},
                             "description": "glTF 2.0 binary of the result on its domain"},
                       409: {"model": ErrorResponse, "description": "job not finished"},
                       **responses(401, 404, 422)})
def get_job_result_glb(job_id: str, svc: JobSvc):
    return Response(svc.result_glb(job_id), media_type="model/gltf-binary")


@router.get("/{job_id}/files/{name}", operation_id="getJobFile", response_class=Response,
            responses={200: {"content": {"application/octet-stream": {
                                 "schema": {"type": "string", "format": "binary"}}},
                             "description": "a file the job produced (its media type: PNG "
                             "image, JPEG, glTF binary, ...); listed in the result's `files`"},
                       409: {"model": ErrorResponse, "description": "job not finished"},
                       **responses(401, 404)})
def get_job_file(job_id: str, name: str, svc: JobSvc):
    data, media_type = svc.result_file(job_id, name)
    return Response(data, media_type=media_type)


@router.get("/{job_id}/arrays/{name}/rows/{row}", operation_id="getJobResultRow",
            response_model=ArrayRow,
            responses={409: {"model": ErrorResponse, "description": "job not finished"},
                       **responses(401, 404, 422)})
def get_job_result_row(job_id: str, name: str, row: int, svc: JobSvc):
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
            data = JobOut.from_row(current).model_dump_json()
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
