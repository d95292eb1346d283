"""Huey instance from the settings: SqliteHuey (embedded), RedisHuey (scaled out) or
immediate mode (tests).  The task code is the same for all: it receives a job id only."""

from __future__ import annotations

from huey import Huey, RedisHuey, SqliteHuey

from service.settings import Settings

TASK_NAME = "otgeo.run_job"


def make_huey(settings: Settings) -> Huey:
    if settings.queue == "redis":
        return RedisHuey(settings.queue_name, url=settings.redis_url, results=False,
                         blocking=True, read_timeout=1)
    if settings.queue == "immediate":
        return SqliteHuey(settings.queue_name, results=False, immediate=True)
    settings.ensure_dirs()
    return SqliteHuey(settings.queue_name, filename=str(settings.data_dir / "queue.sqlite3"),
                      results=False)


def register_task(huey: Huey, run):
    """Register ``run(job_id)`` as the one queue task; returns the task wrapper."""

    @huey.task(name=TASK_NAME)
    def run_job(job_id: str) -> None:
        run(job_id)

    return run_job
