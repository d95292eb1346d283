"""The OpenAPI examples of the request models are valid requests (SDKs build requests from
them), and the operations of issue 26 have one."""

from __future__ import annotations

import pytest

from service.operations import build_registry

WITH_EXAMPLES = {"volumetric-distances", "volumetric-paths", "feature-distances",
                 "anisotropic-distances", "shape-interpolations", "soft-map-analyses",
                 "metric-histogram-propagations", "w1-barycenters", "path-plans"}
REGISTRY = build_registry()


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_examples_validate_against_their_model(name):
    model = REGISTRY[name].request_model
    examples = model.model_json_schema().get("examples", [])
    if name in WITH_EXAMPLES:
        assert examples, name
    for example in examples:
        model.model_validate(example)
