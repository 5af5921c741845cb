"""The shared-token check: every call but the health service's must carry the server's
`graft-token` metadata, or it is refused with UNAUTHENTICATED."""

from __future__ import annotations

import hmac
from collections.abc import Awaitable, Callable
from typing import Any, NoReturn, Optional

import grpc

from service.replay.codec import TOKEN_METADATA_KEY

_HANDLER_KINDS = {
    (False, False): grpc.unary_unary_rpc_method_handler,
    (True, False): grpc.stream_unary_rpc_method_handler,
    (False, True): grpc.unary_stream_rpc_method_handler,
    (True, True): grpc.stream_stream_rpc_method_handler,
}


async def _refuse(request: object, context: grpc.aio.ServicerContext[Any, Any]) -> NoReturn:
    await context.abort(grpc.StatusCode.UNAUTHENTICATED, "missing or wrong graft-token metadata")


class TokenInterceptor(grpc.aio.ServerInterceptor):
    """Refuses every call whose `graft-token` metadata does not match (constant-time)."""

    def __init__(self, token: str) -> None:
        self._token = token.encode()

    async def intercept_service(
        self,
        continuation: Callable[
            [grpc.HandlerCallDetails], Awaitable[Optional[grpc.RpcMethodHandler[Any, Any]]]
        ],
        handler_call_details: grpc.HandlerCallDetails,
    ) -> Optional[grpc.RpcMethodHandler[Any, Any]]:
        handler = await continuation(handler_call_details)
        if handler is None or handler_call_details.method.startswith("/grpc.health"):
            return handler
        sent = dict(handler_call_details.invocation_metadata or ()).get(TOKEN_METADATA_KEY, "")
        if hmac.compare_digest(str(sent).encode(), self._token):
            return handler
        make = _HANDLER_KINDS[(handler.request_streaming, handler.response_streaming)]
        refusal: grpc.RpcMethodHandler[Any, Any] = make(
            _refuse, request_deserializer=handler.request_deserializer
        )
        return refusal
