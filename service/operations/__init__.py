"""The service's operations: each family module lists its ``OPERATIONS``.

:func:`build_registry` collects them into a fresh ``name -> Operation`` mapping; the app
factory and every worker's runtime build their own (nothing is registered at import).
Add a family by listing its module in ``FAMILIES``.
"""

from service.operations import (
    anisotropy,
    applications,
    barycenter_batches,
    color,
    features,
    histograms,
    matrices,
    metric_histograms,
    shapes,
    soft_map_analyses,
    softmaps,
    transport,
    volumetric,
    w1_applications,
)
from service.operations.base import (
    Operation,
    OperationOutput,
    ResultFile,
    RunContext,
    SubmitContext,
)

FAMILIES = (transport, barycenter_batches, matrices, histograms, color, softmaps, applications,
            volumetric, features, anisotropy, shapes, soft_map_analyses, metric_histograms,
            w1_applications)


class Registry(dict):
    """``name -> Operation``; lookups of unknown names are 404s naming the operation."""

    def get_operation(self, name: str) -> Operation:
        from service.errors import NotFound

        try:
            return self[name]
        except KeyError:
            raise NotFound(f"unknown operation {name!r}", field="operation") from None

    def serves_glb(self, name: str, domain_id: str | None) -> bool:
        """Whether a job of operation ``name`` on ``domain_id`` has a ``result.glb`` (an
        operation no longer registered: none)."""
        op = self.get(name)
        return op is not None and op.serves_glb(domain_id)


def build_registry(families=FAMILIES) -> Registry:
    registry = Registry()
    for family in families:
        for op in family.OPERATIONS:
            if op.name in registry:
                raise ValueError(f"operation {op.name!r} registered twice")
            if any(o.operation_id == op.operation_id for o in registry.values()):
                raise ValueError(f"operation id {op.operation_id!r} used twice")
            registry[op.name] = op
    return registry


__all__ = ["FAMILIES", "Operation", "OperationOutput", "Registry", "ResultFile", "RunContext",
           "SubmitContext", "build_registry"]
