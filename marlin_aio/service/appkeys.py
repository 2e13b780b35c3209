"""OctoPrint's application keys: an app asks for a key, the service's owner approves or denies, the app polls.

The flow of OctoPrint's bundled appkeys plugin, which Home Assistant's integration (pyoctoprintapi), OctoPrint's
own clients and the slicers follow: `GET /plugin/appkeys/probe` (204: the flow is on), `POST
/plugin/appkeys/request` with the app's name (201, and where to poll), then `GET /plugin/appkeys/request/<token>`
until the decision: 202 while it waits, 200 with the key once (the decision is then forgotten), 404 when denied,
unknown or expired. Nothing is handed out without the owner's approval: the service says that a request waits and
how to approve it (`marlin-temp keys approve TOKEN`), through its own socket, which only its owner can reach.

Keys issued this way are kept in a file of the service's private folder (owner-only, as the API key beside it), so
they outlive a restart; they are listed and revoked with `marlin-temp keys`. Each works as the service's own API
key on the OctoPrint API.

Bounds, as every door has them: at most `MAX_REQUESTS_PER_MINUTE` requests are taken a minute (OctoPrint's plugin
limits them too: the endpoint needs no key, and each request is a line on the owner's console), at most
`MAX_PENDING` wait at once (the oldest then goes), a request is forgotten `REQUEST_TTL_S` after it was made, and at
most `MAX_KEYS` keys are kept.
"""

from __future__ import annotations

import contextlib
import hmac
import json
import os
import secrets
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

__all__ = [
    "MAX_KEYS",
    "MAX_PENDING",
    "MAX_REQUESTS_PER_MINUTE",
    "REQUEST_TTL_S",
    "AppKeyError",
    "AppKeys",
    "IssuedKey",
    "KeyRequest",
    "TooManyRequestsError",
]

#: Requests taken in any minute; more are refused (HTTP 429) until the minute has passed.
MAX_REQUESTS_PER_MINUTE = 10
#: Requests waiting for a decision at once; a further one pushes the oldest out.
MAX_PENDING = 16
#: How long a request waits for its decision (OctoPrint: 10 minutes).
REQUEST_TTL_S = 600.0
#: Keys kept; a request is refused beyond this (revoke one first).
MAX_KEYS = 64
#: The longest app or user name kept (they are shown to the owner and written to the file).
MAX_NAME_CHARS = 100


class AppKeyError(ValueError):
    """A request for a key the service cannot take (no app name, too many keys), or a decision about a request
    it does not know."""


class TooManyRequestsError(AppKeyError):
    """More requests for keys than `MAX_REQUESTS_PER_MINUTE`: this one was not taken."""


@dataclass
class KeyRequest:
    """An app's request for a key, waiting for the owner's decision (or decided, waiting for the app's poll)."""

    token: str
    app: str
    user: str
    made_s: float
    decision: bool | None = None
    key: str | None = None


@dataclass(frozen=True)
class IssuedKey:
    """A key the owner approved: which app asked, for which user, and when."""

    app: str
    user: str
    key: str
    issued: float
    """Wall-clock time (seconds since the epoch)."""

    def shown(self) -> dict[str, object]:
        """What `marlin-temp keys list` shows of it: never the whole key, only its first characters."""
        return {"app": self.app, "user": self.user, "key": self.key[:6] + "...", "issued": self.issued}


def _name(value: object, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise AppKeyError(f'the request needs "{what}": a name')
    text = "".join(ch if ch.isprintable() else "?" for ch in value.strip())
    return text[:MAX_NAME_CHARS]


class AppKeys:
    """The requests waiting and the keys issued, kept in `path` (None: in memory only, for tests).

    Args:
        path: the file the issued keys are kept in (made owner-only).
        clock: monotonic seconds, for the requests' lifetime.
    """

    def __init__(self, path: Path | None, clock: Callable[[], float] = time.monotonic) -> None:
        self._path = path
        self._clock = clock
        self._requests: dict[str, KeyRequest] = {}
        self._recent: deque[float] = deque()  # when the requests of the last minute were made
        self._keys: list[IssuedKey] = self._load()

    # ------------------------------------------------------------------------------------------- the app's side

    def request(self, app: object, user: object = None) -> KeyRequest:
        """A new request of `app` (for `user`, if given), waiting for the owner's decision.

        Raises:
            TooManyRequestsError: `MAX_REQUESTS_PER_MINUTE` were taken in the last minute.
            AppKeyError: no app name, or the service keeps as many keys as it may.
        """
        now = self._clock()
        while self._recent and self._recent[0] <= now - 60.0:
            self._recent.popleft()
        if len(self._recent) >= MAX_REQUESTS_PER_MINUTE:
            raise TooManyRequestsError(f"more than {MAX_REQUESTS_PER_MINUTE} requests for keys a minute: ask later")
        name = _name(app, "app")
        who = "" if user is None or user == "" else _name(user, "user")
        if len(self._keys) >= MAX_KEYS:
            raise AppKeyError(f"the service keeps {MAX_KEYS} keys already: revoke one (marlin-temp keys revoke)")
        self._expire()
        while len(self._requests) >= MAX_PENDING:
            del self._requests[next(iter(self._requests))]
        # Hexadecimal: a token typed as a command's argument must never start with `-` (an option to the shell's
        # eye), which a URL-safe one may.
        self._recent.append(now)
        request = KeyRequest(secrets.token_hex(12), name, who, now)
        self._requests[request.token] = request
        return request

    def poll(self, token: str) -> tuple[Literal["pending", "granted", "unknown"], str | None]:
        """The decision on request `token`: pending; granted, with the key (said once: the request is then
        forgotten); or unknown (denied, expired, or never made)."""
        self._expire()
        request = self._requests.get(token)
        if request is None or request.decision is False:
            self._requests.pop(token, None)
            return "unknown", None
        if request.decision is None:
            return "pending", None
        del self._requests[token]
        return "granted", request.key

    # ------------------------------------------------------------------------------------------- the owner's side

    def pending(self) -> list[KeyRequest]:
        """The requests waiting for a decision, oldest first."""
        self._expire()
        return [request for request in self._requests.values() if request.decision is None]

    def decide(self, token: str, approve: bool) -> KeyRequest:
        """Approve (a key is issued and kept) or deny request `token`.

        Raises:
            AppKeyError: no such request waits (unknown, expired, or decided already).
        """
        self._expire()
        request = self._requests.get(token)
        if request is None or request.decision is not None:
            waiting = ", ".join(r.token for r in self.pending()) or "none"
            raise AppKeyError(f"no request {token!r} waits for a decision (waiting: {waiting})")
        request.decision = approve
        if approve:
            key = secrets.token_hex(16).upper()  # OctoPrint's keys look like this: 32 hexadecimal digits
            request.key = key
            self._keys.append(IssuedKey(request.app, request.user, key, time.time()))
            self._save()
        return request

    def issued(self) -> list[IssuedKey]:
        """The keys kept, oldest first."""
        return list(self._keys)

    def revoke(self, what: str) -> list[IssuedKey]:
        """Revoke the keys that start with `what` (at least 6 characters of a key), or that an app of that name
        (any case) holds; return them.

        Raises:
            AppKeyError: nothing matches.
        """
        wanted = what.strip()
        gone = [
            key
            for key in self._keys
            if (len(wanted) >= 6 and key.key.startswith(wanted.removesuffix("...")))
            or key.app.lower() == wanted.lower()
        ]
        if not wanted or not gone:
            apps = ", ".join(sorted({key.app for key in self._keys})) or "none"
            raise AppKeyError(f"no key of {what!r} (apps holding keys: {apps})")
        self._keys = [key for key in self._keys if key not in gone]
        self._save()
        return gone

    def valid(self, given: bytes) -> bool:
        """True if `given` is a key issued here (compared in constant time, each one)."""
        found = False
        for key in self._keys:
            found |= hmac.compare_digest(given, key.key.encode())
        return found

    # ------------------------------------------------------------------------------------------- keeping

    def _expire(self) -> None:
        oldest = self._clock() - REQUEST_TTL_S
        for token in [t for t, r in self._requests.items() if r.made_s < oldest]:
            del self._requests[token]

    def _load(self) -> list[IssuedKey]:
        if self._path is None:
            return []
        try:
            data = json.loads(self._path.read_text())
        except FileNotFoundError:
            return []
        except (OSError, ValueError) as exc:
            raise AppKeyError(f"cannot read the app keys in {self._path}: {exc}") from None
        keys = []
        for item in data if isinstance(data, list) else []:
            with contextlib.suppress(KeyError, TypeError, ValueError):
                keys.append(IssuedKey(str(item["app"]), str(item["user"]), str(item["key"]), float(item["issued"])))
        return keys[:MAX_KEYS]

    def _save(self) -> None:
        if self._path is None:
            return
        data = [{"app": k.app, "user": k.user, "key": k.key, "issued": k.issued} for k in self._keys]
        partial = self._path.with_name(self._path.name + ".new")
        # Written whole under another name, then renamed: a crash leaves the old file or the new one, never half.
        descriptor = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(descriptor, "w") as file:
            json.dump(data, file, indent=1)
        os.replace(partial, self._path)
