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


def upload_arrays(client, tmp_path, vertices, faces, name: str) -> str:
    """Upload a mesh given as arrays (written as OBJ, vertex order kept); its domain id."""
    import trimesh

    path = tmp_path / name
    path.write_text(trimesh.exchange.obj.export_obj(trimesh.Trimesh(vertices, faces,
                                                                    process=False)))
    return upload_mesh(client, path).json()["id"]


def job_result(client, response) -> tuple[str, dict]:
    """``(job id, result document)`` of a job awaited in its submission (``?wait=``), which
    must have succeeded."""
    assert response.status_code == 200, response.text
    job = response.json()
    assert job["state"] == "succeeded", job
    return job["id"], client.get(f"/v1/jobs/{job['id']}/result").json()


def bump_masses(mesh, vertex: int, radius: float):
    """A bump distribution ``{"vertex", "radius"}`` as the service resolves it on ``mesh``
    (masses ``a_j max(0, 1 - d_j / r)``, normalized)."""
    import numpy as np

    d = np.linalg.norm(mesh.vertices - mesh.vertices[vertex], axis=1)
    m = mesh.areas * np.clip(1 - d / radius, 0, None)
    return m / m.sum()
