"""OpenAPI examples of the operations' request models (``model_config = example({...})``).

The docs show them, and tests/service/test_sdk.py submits every one through a generated client
(and tests/service/test_result_budget.py at default sizes), with ``EXAMPLE_ID`` replaced by
stored domain or blob ids: an example must be a request that runs, quickly, on a closed mesh
of a few hundred vertices.
"""

from pydantic import ConfigDict

# Bumps of the examples (vertices present on any mesh of a few hundred vertices).
BUMP_A = {"vertex": 0, "radius": 0.2}
BUMP_B = {"vertex": 100, "radius": 0.2}
# Stands for a stored domain's or blob's id (tests substitute real ids).
EXAMPLE_ID = "0123456789abcdef0123456789abcdef"


def example(body: dict, **schema) -> ConfigDict:
    """``model_config`` giving a request model its OpenAPI example (and the JSON Schema
    keywords ``schema``: rules between fields, see service.operations.base.rules)."""
    return ConfigDict(json_schema_extra={"examples": [body], **schema})
