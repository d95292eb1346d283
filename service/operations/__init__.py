"""Registry of operations: each is a request model, validation and a run function."""

from service.operations.base import Operation, OperationOutput
from service.operations.transport import OPERATIONS as _TRANSPORT

REGISTRY: dict[str, Operation] = {}


def register(op: Operation) -> Operation:
    if op.name in REGISTRY:
        raise ValueError(f"operation {op.name!r} registered twice")
    REGISTRY[op.name] = op
    return op


for _op in _TRANSPORT:
    register(_op)


def get_operation(name: str) -> Operation:
    from service.errors import NotFound

    try:
        return REGISTRY[name]
    except KeyError:
        raise NotFound(f"unknown operation {name!r}", field="operation") from None


__all__ = ["REGISTRY", "Operation", "OperationOutput", "get_operation", "register"]
