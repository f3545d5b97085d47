"""What no web page may do to the station: the checks around every request.

`Guard` is plain ASGI middleware, ahead of every route (pages, API, event stream, static):
- the Host header must name this station (loopback names, the address it listens on, and
  station.yaml's ui.allowed_hosts): a page of another site whose name was pointed at this
  machine (DNS rebinding) gets 421 and nothing else;
- request bodies are capped (API bodies are a few hundred bytes): 413 beyond the cap;
- every response carries nosniff, frame-ancestors 'none' and X-Frame-Options: DENY.

`same_origin_problem` is the Origin/Referer half of the CSRF check the app applies to each
state-changing request (the other half is the session's token in a header).
"""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable, Iterable, MutableMapping
from typing import Any
from urllib.parse import urlsplit

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "::1"})
MAX_BODY_BYTES = 64 * 1024
SECURITY_HEADERS = (
    (b"x-content-type-options", b"nosniff"),
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"same-origin"),
)
FRAME_CSP = b"frame-ancestors 'none'"


def host_name(host_header: str) -> str:
    """'Example.com:8080' -> 'example.com'; '[::1]:80' -> '::1'."""
    text = host_header.strip().lower()
    if text.startswith("["):
        return text[1 : text.find("]")] if "]" in text else text
    return text.rsplit(":", 1)[0] if text.count(":") == 1 else text


def allowed_hosts(listen_host: str, extra: Iterable[str] = ()) -> frozenset[str]:
    hosts = set(LOOPBACK_HOSTS) | {host_name(h) for h in extra}
    if listen_host not in ("0.0.0.0", "::", ""):
        hosts.add(host_name(listen_host) if listen_host.startswith("[") else listen_host.lower())
    return frozenset(hosts)


def same_origin_problem(headers: dict[str, str], scheme: str) -> str | None:
    """Why the request did not come from this station's own pages, or None when it did.

    Browsers send Origin on every cross-origin POST (and on same-origin fetch POSTs); when a
    client sends neither Origin nor Referer it is not a browser page and the CSRF token alone
    decides."""
    host = headers.get("host", "")
    expected = f"{scheme}://{host}".lower()
    origin = headers.get("origin")
    if origin is not None:
        if origin.lower() != expected:
            return f"request from another site ({origin[:100]}) refused"
        return None
    referer = headers.get("referer")
    if referer is not None:
        parts = urlsplit(referer)
        if f"{parts.scheme}://{parts.netloc}".lower() != expected:
            return "request from another site (its Referer is not this station) refused"
    return None


class Guard:
    def __init__(self, app: ASGIApp, hosts: frozenset[str], max_body_bytes: int = MAX_BODY_BYTES):
        self.app = app
        self.hosts = hosts
        self.max_body_bytes = max_body_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        host = host_name(headers.get("host", ""))
        if host not in self.hosts:
            await _reply(
                send,
                421,
                f"this station does not answer to the host name {host[:100]!r}; use its own "
                "address (an engineer may add a name under ui.allowed_hosts in station.yaml)",
            )
            return
        length = headers.get("content-length", "")
        if length and (not length.isdigit() or int(length) > self.max_body_bytes):
            await _reply(send, 413, f"request body over {self.max_body_bytes} bytes refused")
            return
        body_receive = receive
        if scope["method"] in ("POST", "PUT", "PATCH", "DELETE"):
            body = await _read_body(receive, self.max_body_bytes)
            if body is None:
                await _reply(send, 413, f"request body over {self.max_body_bytes} bytes refused")
                return
            body_receive = _replay(body, receive)

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                raw = list(message.get("headers", []))
                names = {k.lower() for k, _ in raw}
                raw += [(k, v) for k, v in SECURITY_HEADERS if k not in names]
                if b"content-security-policy" not in names:
                    raw.append((b"content-security-policy", FRAME_CSP))
                message["headers"] = raw
            await send(message)

        await self.app(scope, body_receive, send_with_headers)


async def _read_body(receive: Receive, limit: int) -> bytes | None:
    chunks: list[bytes] = []
    size = 0
    while True:
        message = await receive()
        if message["type"] != "http.request":
            return b"".join(chunks)  # the client went away; the route will see an empty body
        chunk = message.get("body", b"")
        size += len(chunk)
        if size > limit:
            return None
        chunks.append(chunk)
        if not message.get("more_body", False):
            return b"".join(chunks)


def _replay(body: bytes, receive: Receive) -> Receive:
    sent = False

    async def replay() -> Message:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay


async def _reply(send: Send, status: int, message: str) -> None:
    body = json.dumps({"error": message}).encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        *SECURITY_HEADERS,
        (b"content-security-policy", FRAME_CSP),
    ]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
