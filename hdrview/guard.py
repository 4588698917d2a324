"""Who may open the inspector: its own address only, and only with the token printed at start.

viser does not check the WebSocket ``Origin`` nor the ``Host`` header, so any web page a user
visits could open ``ws://127.0.0.1:PORT``, type a path and download the result (a browser lets a
page do that to loopback; DNS rebinding defeats a check of the address alone). Every HTTP request
and WebSocket handshake is checked here before viser sees it:

* ``Host`` must name the inspector's own address and port (``127.0.0.1``, ``localhost``,
  ``[::1]`` or the address it listens on, or a host of ``--allow-origin``): a rebinding name
  such as ``evil.example:8080`` that resolves to 127.0.0.1 is refused;
* ``Origin``, when the client sends one (browsers always do for a WebSocket), must be one of
  those same addresses (``http://host:port``) or an ``--allow-origin`` value;
* the access token (``secrets.token_urlsafe``, printed at start as ``http://...:PORT/?token=...``,
  as Jupyter does) must come with the request, in the query or in the ``hdrview_token`` cookie
  that the first page sets (``SameSite=Strict``: a foreign page's requests do not carry it).
  ``--no-token`` switches the token off (the address checks stay).

Refusals are ``403`` answers with one line saying why, sent before any viser message.
"""

from __future__ import annotations

import contextlib
import hmac
import http
import logging
import secrets
from collections.abc import Callable, Iterable, Iterator
from http.cookies import SimpleCookie
from typing import Any
from urllib.parse import parse_qs, urlsplit

log = logging.getLogger(__name__)

__all__ = ["ConnectionGuard", "install_guard", "COOKIE"]

COOKIE = "hdrview_token"
_LOOPBACK = ("127.0.0.1", "localhost", "::1")


def _one(headers: Any, name: str) -> str | None:
    """The single value of header ``name`` (``None`` when absent); two values are refused."""
    get_all = getattr(headers, "get_all", None)
    values = (
        list(get_all(name))
        if get_all is not None
        else ([] if headers.get(name) is None else [headers.get(name)])
    )
    if len(values) > 1:
        raise LookupError(f"{len(values)} {name} headers")
    return values[0] if values else None


def _split_host(value: str) -> tuple[str, int | None]:
    """``host[:port]`` (IPv6 in brackets) -> (lower-case host without brackets, port)."""
    v = value.strip().lower()
    if v.startswith("["):
        host, _, rest = v[1:].partition("]")
        port = rest[1:] if rest.startswith(":") else ""
    else:
        host, _, port = v.partition(":")
    try:
        return host, int(port) if port else None
    except ValueError:
        return host, -1


class ConnectionGuard:
    """Checks ``Host``, ``Origin`` and the token of every request (module docstring).

    ``port`` is a callable giving the port the server bound (known only once it listens);
    ``bind_host`` the address it listens on; ``allow_origins`` extra origins such as
    ``https://my.proxy:443``; ``token`` ``None`` for no token.
    """

    def __init__(
        self,
        port: Callable[[], int],
        *,
        bind_host: str = "127.0.0.1",
        allow_origins: Iterable[str] = (),
        token: str | None = "",
    ) -> None:
        self._port = port
        hosts = set(_LOOPBACK)
        if bind_host not in ("0.0.0.0", "::", ""):
            hosts.add(bind_host.strip("[]").lower())
        self._hosts = hosts
        self._origins: set[tuple[str, str, int | None]] = set()
        for o in allow_origins:
            parts = urlsplit(o if "://" in o else f"http://{o}")
            host, port_ = _split_host(parts.netloc)
            if not host:
                raise ValueError(f"--allow-origin {o!r} names no host")
            self._origins.add((parts.scheme or "http", host, port_))
        self.token = secrets.token_urlsafe(24) if token == "" else token

    def url(self, host: str = "127.0.0.1") -> str:
        """The address to open, with the token when there is one."""
        h = f"[{host}]" if ":" in host else host
        base = f"http://{h}:{self._port()}/"
        return base if self.token is None else f"{base}?token={self.token}"

    # -- the checks ----------------------------------------------------------------------------

    def _host_allowed(self, host: str, port: int | None) -> bool:
        if host in self._hosts and port == self._port():
            return True
        return any(host == h and (p is None or p == port) for _, h, p in self._origins)

    def _origin_allowed(self, origin: str) -> bool:
        parts = urlsplit(origin)
        host, port = _split_host(parts.netloc)
        if parts.scheme in ("http", "https") and host in self._hosts and port == self._port():
            return True
        return any(
            parts.scheme == s and host == h and (p is None or p == port)
            for s, h, p in self._origins
        )

    def _token_of(self, path: str, headers: Any) -> str | None:
        query = parse_qs(urlsplit(path).query)
        if "token" in query:
            return query["token"][0]
        cookie = SimpleCookie()
        with contextlib.suppress(Exception):
            cookie.load(headers.get("Cookie", "") or "")
        morsel = cookie.get(COOKIE)
        return None if morsel is None else morsel.value

    def refusal(self, path: str, headers: Any) -> str | None:
        """Why a request is refused, or ``None`` when it may go on."""
        try:
            host_header = _one(headers, "Host")
            origin = _one(headers, "Origin")
        except LookupError as exc:
            return str(exc)
        if not host_header:
            return "no Host header"
        host, port = _split_host(host_header)
        if not self._host_allowed(host, port):
            return f"Host {host_header!r} is not this inspector's address"
        if origin is not None and origin != "null" and not self._origin_allowed(origin):
            return f"Origin {origin!r} may not use this inspector (see --allow-origin)"
        if origin == "null":
            return "Origin 'null' (a sandboxed or file page) may not use this inspector"
        if self.token is not None:
            given = self._token_of(path, headers)
            if given is None or not hmac.compare_digest(
                given.encode("utf-8", "replace"), self.token.encode()
            ):
                return (
                    "missing or wrong access token: open the address hdrview printed at "
                    "start (it ends in ?token=...)"
                )
        return None

    def wrap(self, process_request: Callable[..., Any] | None) -> Callable[..., Any]:
        """A ``process_request`` for ``websockets.serve`` that checks first, then lets viser
        serve the page (setting the token cookie on it)."""
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        guard = self

        def guarded(connection: Any, request: Any) -> Any:
            why = guard.refusal(request.path, request.headers)
            if why is not None:
                log.warning(
                    "refused %s %s: %s",
                    request.headers.get("Origin") or "-",
                    request.path.partition("?")[0],
                    why,
                )
                body = f"hdrview: refused: {why}\n".encode()
                return Response(
                    http.HTTPStatus.FORBIDDEN,
                    "Forbidden",
                    Headers(
                        {
                            "Content-Type": "text/plain; charset=utf-8",
                            "Content-Length": str(len(body)),
                        }
                    ),
                    body,
                )
            response = None if process_request is None else process_request(connection, request)
            if (
                response is not None
                and guard.token is not None
                and "token" in parse_qs(urlsplit(request.path).query)
            ):
                response.headers["Set-Cookie"] = (
                    f"{COOKIE}={guard.token}; Path=/; HttpOnly; SameSite=Strict"
                )
            return response

        return guarded


@contextlib.contextmanager
def install_guard(guard: ConnectionGuard) -> Iterator[None]:
    """While a :class:`viser.ViserServer` is being created, its WebSocket server is started with
    ``guard`` in front of viser's own request handler (viser has no hook for this)."""
    from viser.infra import _infra

    serve_module = _infra.websockets.asyncio.server
    original = serve_module.serve

    def serve(*args: Any, **kwargs: Any) -> Any:
        kwargs["process_request"] = guard.wrap(kwargs.get("process_request"))
        return original(*args, **kwargs)

    # viser has no hook: its module's serve (a class) is replaced by a function while it starts
    serve_module.serve = serve  # type: ignore[misc,assignment]  # a deliberate monkeypatch
    try:
        yield
    finally:
        serve_module.serve = original  # type: ignore[misc]  # undoing the monkeypatch
