"""Helpers shared by the service tests (import as ``from service_testing import ...``)."""


def upload_mesh(client, path, **data):
    with open(path, "rb") as fh:
        return client.post("/v1/domains", files={"file": (path.name, fh)}, data=data)


def assert_error(response, status: int, field: str | None, code: str | None = None) -> dict:
    assert response.status_code == status, response.text
    err = response.json()["error"]
    assert set(err) == {"code", "message", "field"}
    assert err["field"] == field, err
    if code is not None:
        assert err["code"] == code, err
    assert err["message"]
    return err


def assert_has_result(job: dict) -> dict:
    """A finished job with a readable result: ``succeeded``, or ``failed`` with code
    ``not_converged`` (tests that cap ``max_iter`` for speed read the partial result)."""
    if job["state"] != "succeeded":
        assert job["state"] == "failed" and job["error"]["code"] == "not_converged", job
    return job
