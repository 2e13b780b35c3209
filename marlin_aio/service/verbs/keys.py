"""The OctoPrint API's application keys, decided by the service's owner: the requests waiting, approve, deny, the
keys kept, revoke (`marlin_aio.service.appkeys`). Offered on the owner's Unix socket only: an app that asks for a
key must never be the one that grants it, so neither TCP nor MQTT nor the HTTP API offers these. The keys are the
service's, whichever of its printers a call names (the OctoPrint API speaks for one of them)."""

from __future__ import annotations

from typing import Any

from marlin_aio.protocol.rpc import INVALID_PARAMS, RpcError
from marlin_aio.service.appkeys import AppKeyError
from marlin_aio.service.verbs.table import REQUIRED, Access, Arg, Context, Door, verb

__all__: list[str] = []

#: The owner's Unix socket alone.
_OWNER: frozenset[Door] = frozenset({"socket"})


def _pending(context: Context) -> list[dict[str, object]]:
    return [
        {"token": request.token, "app": request.app, "user": request.user}
        for request in context.owner.app_keys.pending()
    ]


@verb("keys", access=Access.READ, doors=_OWNER, result="{pending: [{token, app, user}], issued}")
async def keys(context: Context, args: dict[str, Any]) -> object:
    """The OctoPrint API's app-key requests waiting for a decision, and the keys issued (shown by their start)."""
    issued = [key.shown() for key in context.owner.app_keys.issued()]
    return {"pending": _pending(context), "issued": issued}


async def _decide(context: Context, token: str, approve: bool) -> object:
    try:
        request = context.owner.app_keys.decide(token, approve)
    except AppKeyError as exc:
        raise RpcError(INVALID_PARAMS, str(exc)) from None
    return {"token": request.token, "app": request.app, "user": request.user, "approved": approve}


@verb(
    "approve_key",
    Arg("token", str, REQUIRED, "the request's token, as `keys` lists it"),
    access=Access.CONTROL,
    doors=_OWNER,
    result="{token, app, user, approved}",
)
async def approve_key(context: Context, args: dict[str, Any]) -> object:
    """Approve an app's request: a key is issued, kept, and handed to the app at its next poll."""
    return await _decide(context, args["token"], True)


@verb(
    "deny_key",
    Arg("token", str, REQUIRED, "the request's token, as `keys` lists it"),
    access=Access.CONTROL,
    doors=_OWNER,
    result="{token, app, user, approved}",
)
async def deny_key(context: Context, args: dict[str, Any]) -> object:
    """Deny an app's request: its next poll is told no (404), and nothing is issued."""
    return await _decide(context, args["token"], False)


@verb(
    "revoke_key",
    Arg("key", str, REQUIRED, "the key's first characters (at least 6), or the app's name"),
    access=Access.CONTROL,
    doors=_OWNER,
    result="{revoked: [{app, user, key, issued}]}",
)
async def revoke_key(context: Context, args: dict[str, Any]) -> object:
    """Revoke issued keys (by their start, or every key of an app): the API refuses them from now on."""
    try:
        gone = context.owner.app_keys.revoke(args["key"])
    except AppKeyError as exc:
        raise RpcError(INVALID_PARAMS, str(exc)) from None
    return {"revoked": [key.shown() for key in gone]}
