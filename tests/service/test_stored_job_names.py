"""A job stored before the one vocabulary (issue 41: ``route``/``algorithm``/``solver`` as
an algorithm choice, ``routes`` per pair) still reads and runs as it was decided
(service.renames)."""

from __future__ import annotations

import time

import pytest

from service.domains import DomainService
from service.job_service import JobService
from service.jobs.db import QUEUED, SUCCEEDED, JobRow
from service.renames import DECISION, PARAMS, SOLVER_ARGUMENTS, current_decision
from service.runtime import Runtime
from service.schemas import GridSpec, JobOut
from service.settings import Settings

BUMPS = {"mu0": {"vertex": 0, "radius": 0.2}, "mu1": {"vertex": 35, "radius": 0.2}}


def _old(data: dict, names: dict[str, str]) -> dict:
    """``data`` under the old names (the inverse of ``names``)."""
    back = {new: old for old, new in names.items()}
    return {back.get(k, k): v for k, v in data.items()}


def _old_decision(decision: dict) -> dict:
    old = _old(decision, DECISION)
    if old.get("solver_arguments"):
        back = {"method": "algorithm" if decision["metric"] == "w1" else "route"}
        old["solver_arguments"] = {back.get(k, k): v
                                   for k, v in old["solver_arguments"].items()}
    return old


@pytest.mark.parametrize(("operation", "body"), [
    ("distances", {**BUMPS, "method": "convolutional", "gamma": 0.01}),
    ("distances", {**BUMPS, "method": "exact"}),
    ("distance-matrices", {"distributions": [BUMPS["mu0"], BUMPS["mu1"],
                                             {"vertex": 20, "radius": 0.2}],
                           "method": "convolutional", "gamma": 0.01}),
])
def test_a_job_stored_under_the_old_names_runs_as_decided(tmp_path, operation, body):
    api = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="api")
    try:
        meta, _ = DomainService(api).from_spec(GridSpec(kind="grid", shape=[6, 6]))
        request = api.operations.get_operation(operation).request_model.model_validate(body)
        new = JobService(api).create(operation, meta["id"], request)
    finally:
        api.close()
    params, decision = _old(body, PARAMS[operation]), _old_decision(new.decision)
    assert params != body and decision != new.decision  # really stored the old way
    rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="worker")
    try:
        now = time.time()
        rt.repo.create(JobRow(id="old", operation=operation, domain_id=meta["id"],
                              params=params, decision=decision, state=QUEUED, queue="short",
                              cost=1.0, attempts=0, max_attempts=1, cancel_requested=False,
                              time_limit=60.0, created_at=now, enqueued_at=now))
        shown = JobOut.from_row(rt.repo.get("old"), rt.operations)
        assert shown.decision == new.decision  # read under the new names
        rt.runner.run("old")
        row = rt.repo.get("old")
        assert row.state == SUCCEEDED, row.error
        result = row.result or rt.store.get_result("old")
        assert result["decision"] == result["values"]["decision"] == new.decision
    finally:
        rt.close()


def test_renaming_keeps_a_key_already_new_and_touches_nothing_else():
    old = {"route": "exact", "method": "convolutional", "gamma": 0.5,
           "solver_arguments": {"route": "exact"}}
    assert current_decision(old) == {"method": "convolutional", "gamma": 0.5,
                                     "solver_arguments": {"method": "exact"}}
    assert current_decision(None) is None
    assert set(SOLVER_ARGUMENTS.values()) == {"method"}
