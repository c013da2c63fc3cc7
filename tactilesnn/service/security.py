"""What a web page in the user's browser may do to a service on 127.0.0.1, and the guards.

Threat model (the service listens on loopback by default; any page the user visits can send
requests there):

- **Cross-site requests (CSRF).** A page can POST to ``http://127.0.0.1:8000`` without a CORS
  preflight if the body's content type is ``text/plain``, form-encoded or multipart, or missing
  (``fetch(..., {mode: "no-cors"})``). The JSON and ``.npy`` endpoints therefore accept only
  ``application/json`` and ``application/x-npy`` / ``application/octet-stream`` (415 otherwise): a
  browser sends those only after a preflight, which this service never answers with CORS headers.
  On top of that, a request whose ``Origin`` header names another origin than the ``Host`` it
  was sent to is refused (403) for every method but GET/HEAD; clients that are not browsers
  (curl, ``tactilesnn.service.client``) send no ``Origin`` and are not affected.
- **DNS rebinding.** A page on ``evil.example`` whose name is re-pointed to 127.0.0.1 becomes
  "same origin" and could read ``/v1/model`` or the live events. Every request must name an
  allowed host in ``Host`` (400 otherwise): by default the loopback names when the service is
  bound to loopback, plus the bound address or the machine's name otherwise; ``--allowed-hosts``
  adds more (``*`` turns the check off, for a proxy that checks hosts itself).
- **Script injection.** Everything a request or a model carries (stream ids, class names) reaches
  the live page as data: the page inserts it with ``textContent`` or draws it on a canvas, and
  a Content-Security-Policy allows only the page's own script file (no inline script, no
  ``eval``, no framing by other sites).

Not covered: a process of another local user (the service has no authentication; bind to
loopback on a shared machine at your own risk) and a browser extension with host permissions.
"""

from __future__ import annotations

import ipaddress
import json
import socket
import urllib.parse
from collections.abc import Iterable

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
SAFE_METHODS = frozenset({"GET", "HEAD"})

# applied to every response; the page's policy allows its own script and canvas drawing only
HEADERS = [
    (b"x-content-type-options", b"nosniff"),
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"no-referrer"),
    (b"cross-origin-resource-policy", b"same-origin"),
    (
        b"content-security-policy",
        b"default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
        b"connect-src 'self'; img-src 'self'; base-uri 'none'; form-action 'none'; "
        b"frame-ancestors 'none'",
    ),
]


def _host_name(host_header: str) -> str:
    """``Host`` header value -> host name without port, lower case (``[::1]:8000`` -> ``::1``)."""
    h = host_header.strip().lower()
    if h.startswith("["):
        end = h.find("]")
        return h[1:end] if end > 0 else h
    if h.count(":") == 1:
        h = h.split(":", 1)[0]
    return h.rstrip(".")


def default_allowed_hosts(bind_host: str) -> set[str]:
    """The host names a browser may use to reach a service bound to ``bind_host``."""
    hosts = set(LOOPBACK_NAMES)
    name = _host_name(bind_host) if bind_host else ""
    try:
        wildcard = ipaddress.ip_address(name).is_unspecified
    except ValueError:
        wildcard = False
    if wildcard:
        hosts |= {socket.gethostname().lower(), socket.getfqdn().lower()}
    elif name:
        hosts.add(name)
    return hosts


class BrowserGuard:
    """ASGI middleware: ``Host`` allow-list, same-origin check for state-changing requests, and
    the security headers above on every response."""

    def __init__(self, app, allowed_hosts: Iterable[str]) -> None:
        self.app = app
        hosts = {_host_name(h) for h in allowed_hosts}
        self.any_host = "*" in hosts
        self.allowed_hosts = frozenset(hosts - {"*"})

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        refusal = self.refusal(scope.get("method", "GET"), headers)
        if refusal is not None:
            await _plain(send, *refusal)
            return

        async def send_with_headers(message) -> None:
            if message["type"] == "http.response.start":
                existing = {k.lower() for k, _ in message.get("headers", [])}
                extra = [(k, v) for k, v in HEADERS if k not in existing]
                message = {**message, "headers": [*message.get("headers", []), *extra]}
            await send(message)

        await self.app(scope, receive, send_with_headers)

    def refusal(self, method: str, headers: dict[bytes, str]) -> tuple[int, str] | None:
        """``(status, message)`` if the request must be refused, else None."""
        host = headers.get(b"host", "")
        if not host:
            return 400, "request without a Host header"
        if not self.any_host and _host_name(host) not in self.allowed_hosts:
            return 400, (
                f"host {_host_name(host)[:100]!r} is not allowed (DNS rebinding guard); start "
                "the service with --allowed-hosts naming it"
            )
        origin = headers.get(b"origin")
        if origin is not None and method not in SAFE_METHODS:
            netloc = urllib.parse.urlsplit(origin).netloc.lower() if origin != "null" else ""
            if netloc != host.strip().lower():
                return 403, (
                    f"cross-origin {method} refused (Origin {origin[:100]!r} is not this "
                    "service); send requests from the service's own page or a non-browser client"
                )
        return None


async def _plain(send, status: int, message: str) -> None:
    body = json.dumps({"error": message}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                *HEADERS,
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
