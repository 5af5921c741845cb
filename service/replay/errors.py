"""The errors the replay client raises, one per gRPC status a call can end with."""

from __future__ import annotations

import grpc


class ReplayError(RuntimeError):
    """Base of the typed errors the client raises; `code` is the gRPC status."""

    code = grpc.StatusCode.UNKNOWN


class InvalidArgument(ReplayError):
    code = grpc.StatusCode.INVALID_ARGUMENT


class TableNotFound(ReplayError):
    code = grpc.StatusCode.NOT_FOUND


class DeadlineExceeded(ReplayError):
    code = grpc.StatusCode.DEADLINE_EXCEEDED


class Unauthenticated(ReplayError):
    code = grpc.StatusCode.UNAUTHENTICATED


class ResourceExhausted(ReplayError):
    code = grpc.StatusCode.RESOURCE_EXHAUSTED


class Unavailable(ReplayError):
    code = grpc.StatusCode.UNAVAILABLE


_ERRORS = {cls.code: cls for cls in ReplayError.__subclasses__()}


def typed(error: grpc.RpcError) -> ReplayError:
    """The typed error for a failed call, its message the status name and details."""
    cls = _ERRORS.get(error.code(), ReplayError)
    return cls(f"{error.code().name}: {error.details()}")
