"""The HTTP edge's protections, one ASGI middleware (`HttpEdge`) in front of the routes.

- Host names: every request (reads too) must name the service in its `Host` header (port
  ignored): a loopback name or address (`localhost`, 127.0.0.0/8, `::1`), the bind address
  (`CMRT_API_HOST` / `--host`, unless a wildcard), the host of `CMRT_PUBLIC_URL`, or one of
  `CMRT_ALLOWED_HOSTS` (`*`: any). Anything else is a 400 naming the host, before any route
  runs. This is what stops DNS rebinding: a page of another site whose name is made to resolve
  to this machine is, to the browser, same-origin with the API, but its requests carry the
  page's own name as `Host`. A request without `Host` (HTTP/1.0) is not a browser's and passes.
  `host_warning` says when a wildcard bind leaves only loopback names allowed.
- Methods: `OPTIONS <path>` answers 204 with every method the path has in `Allow`; any other
  method the path lacks answers 405 with the same `Allow` (Starlette alone names only the
  first route matching the path). `HEAD` is served wherever `GET` is: the GET route answers
  and its body is dropped (status and headers, `Content-Length` included, are the GET's).
- Authentication (only when `CMRT_API_TOKEN` is set): `Authorization: Bearer <token>` is
  required on every state-changing request and, unless `CMRT_API_PUBLIC_READS=true`, on the
  read-only data endpoints too (401 otherwise, compared in constant time). Always open: `/health`
  (state only, for orchestrators), the page shells `/dashboard` and `/docs`, their `/static`
  assets and `/openapi.json`; they hold no data, and the dashboard sends the token itself
  (`/dashboard/...`: the job and library pages, shells too). A replay page also opens with a
  signed, short-lived link instead of the header (`service.links`, minted by `POST /links`).
- Other origins: a state-changing request from a page of another origin is refused (403): its
  `Origin` header (which a browser sets on every cross-origin request and a page cannot
  change) must be the service's own: `CMRT_PUBLIC_URL`'s origin, or the request's scheme with
  its `Host` (the address the browser is talking to; behind a TLS proxy, set the public URL);
  one a browser marks `Sec-Fetch-Site: cross-site` or `same-site` (another port or subdomain
  of the same site is another origin) is refused. A request with neither header (curl, the
  CLI) is not a page's. Bodies must also be `application/json` (415, `service.body`), which a
  cross-origin page cannot send without a CORS preflight, and the API grants no CORS.
- Headers on every response: `X-Content-Type-Options: nosniff`, `X-Frame-Options: DENY`,
  `Referrer-Policy: no-referrer` and a Content-Security-Policy: `PAGE_CSP` on the dashboard
  (every `/dashboard...` page),
  `DOCS_CSP` on /docs (Swagger UI sets inline styles), `API_CSP` on everything else; each
  forbids framing (`frame-ancestors 'none'`).
"""

from __future__ import annotations

import hmac
import ipaddress
import json
from collections.abc import Awaitable, Callable
from typing import Any
from urllib.parse import urlsplit

from starlette.routing import Match, Mount

from cmrt.settings import Settings
from service import links

Scope = dict[str, Any]
Receive = Callable[[], Awaitable[dict[str, Any]]]
Send = Callable[[dict[str, Any]], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
#: Paths served to anyone even with a token set (no data behind them).
OPEN_PATHS = frozenset({"/health", "/dashboard", "/docs", "/openapi.json", "/"})
OPEN_PREFIXES = ("/static/", "/dashboard/")

PAGE_CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; "
            "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")
DOCS_CSP = ("default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
            "img-src 'self' data:; font-src 'self' data:; connect-src 'self'; base-uri 'none'; "
            "form-action 'none'; frame-ancestors 'none'")
API_CSP = "default-src 'none'; frame-ancestors 'none'"
_CSP_BY_PATH = {"/dashboard": PAGE_CSP, "/docs": DOCS_CSP}
_COMMON_HEADERS = [(b"x-content-type-options", b"nosniff"), (b"x-frame-options", b"DENY"),
                   (b"referrer-policy", b"no-referrer")]


#: Host names every request may carry besides the configured ones (the loopback addresses,
#: 127.0.0.0/8 and ::1, are recognised as addresses: `_is_loopback`).
LOOPBACK_NAMES = frozenset({"localhost"})
#: Bind addresses meaning "every interface" (the bind address is then no host name to allow).
WILDCARD_BINDS = frozenset({"0.0.0.0", "::", "", "[::]"})


def host_of(value: str) -> str | None:
    """The host name of a `Host` header value, lower-case, without port, brackets or a final
    dot ("[::1]:8000" -> "::1"); None when it is no `host[:port]`."""
    try:
        parts = urlsplit("//" + value.strip())
        _ = parts.port  # ValueError on a port that is not a number in range
    except ValueError:
        return None
    if parts.username is not None or parts.path or parts.query or parts.fragment:
        return None
    host = (parts.hostname or "").rstrip(".")
    return host or None


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def allowed_hosts(settings: Settings) -> frozenset[str]:
    """The host names the service answers to besides loopback addresses (module docstring)."""
    names = set(LOOPBACK_NAMES) | set(settings.allowed_hosts)
    if settings.public_url:
        public = urlsplit(settings.public_url).hostname
        if public:
            names.add(public.rstrip("."))
    if settings.api_host not in WILDCARD_BINDS:
        bind = host_of(settings.api_host if ":" not in settings.api_host
                       or settings.api_host.startswith("[") else f"[{settings.api_host}]")
        if bind:
            names.add(bind)
    return frozenset(names)


def host_allowed(host_header: str | None, names: frozenset[str]) -> bool:
    """Whether a request with this `Host` header value may be answered (`names`: from
    `allowed_hosts`); no header at all is allowed (see the module docstring)."""
    if host_header is None or "*" in names:
        return True
    host = host_of(host_header)
    return host is not None and (host in names or _is_loopback(host))


def host_warning(settings: Settings) -> str | None:
    """What to log at start when a wildcard bind (every interface) answers only loopback
    names: the service is reachable from other machines, but by their address or name only
    once CMRT_PUBLIC_URL or CMRT_ALLOWED_HOSTS names it."""
    if settings.api_host in WILDCARD_BINDS and not settings.public_url \
            and not settings.allowed_hosts:
        return (f"bound to every interface ({settings.api_host or 'all'}) but neither "
                "CMRT_PUBLIC_URL nor CMRT_ALLOWED_HOSTS is set: only requests naming a "
                "loopback host (localhost, 127.0.0.1, ::1) are answered; others get 400 "
                "(set CMRT_ALLOWED_HOSTS to the names clients use)")
    return None


#: Methods probed when computing a path's `Allow` header.
_METHODS = ("GET", "POST", "PUT", "PATCH", "DELETE")
#: Paths whose `Allow` set `HttpEdge` remembers. Probing every route with every method costs
#: about 0.35 ms, more than the rest of a `/health` request; the routes are fixed once the app
#: serves, so a path's set never changes. Past this many paths (ids in them) the oldest are
#: forgotten: memory stays bounded whatever paths clients send.
ALLOW_MEMO_PATHS = 4096


def allowed_methods(app: Any, scope: Scope) -> list[str]:
    """Every method some route of `app` serves at the request's path (HEAD with GET), plus
    OPTIONS; empty when no route has the path. Uses only the routes' public `matches`."""
    methods: set[str] = set()
    for route in app.routes:
        if isinstance(route, Mount):  # static files: read-only
            if route.matches(scope)[0] != Match.NONE:
                methods |= {"GET", "HEAD"}
            continue
        methods |= {m for m in _METHODS
                    if route.matches({**scope, "method": m})[0] == Match.FULL}
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods | {"OPTIONS"}) if methods else []


def token_of(settings: Settings) -> str:
    """The configured API token, "" when authentication is off."""
    return settings.api_token.get_secret_value() if settings.api_token else ""


def needs_token(settings: Settings, method: str, path: str) -> bool:
    """Whether a request needs the bearer token (see the module docstring)."""
    if not token_of(settings) or path in OPEN_PATHS or path.startswith(OPEN_PREFIXES):
        return False
    return method.upper() not in SAFE_METHODS or not settings.api_public_reads


class HttpEdge:
    """See the module docstring. `app` is the FastAPI app whose routes are consulted."""

    def __init__(self, asgi: ASGIApp, *, app: Any, settings: Settings) -> None:
        self.asgi = asgi
        self.app = app
        self.settings = settings
        self.secret = token_of(settings)  # the signed links' key
        self.token = self.secret.encode()  # compared with the bearer header's bytes
        self.hosts = allowed_hosts(settings)
        self._allow: dict[tuple[str, str], list[str]] = {}  # see ALLOW_MEMO_PATHS

    def allowed(self, scope: Scope) -> list[str]:
        """`allowed_methods(self.app, scope)`, remembered per path (ALLOW_MEMO_PATHS)."""
        key = (scope.get("root_path", ""), scope["path"])
        methods = self._allow.get(key)
        if methods is None:
            methods = allowed_methods(self.app, scope)
            if len(self._allow) >= ALLOW_MEMO_PATHS:
                del self._allow[next(iter(self._allow))]
            self._allow[key] = methods
        return methods

    def _token_ok(self, scope: Scope) -> bool:
        for k, v in scope.get("headers", []):
            if k == b"authorization":
                scheme, _, given = v.partition(b" ")
                return scheme.lower() == b"bearer" and hmac.compare_digest(given.strip(),
                                                                           self.token)
        return False

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.asgi(scope, receive, send)
            return
        path, method = scope["path"], scope["method"]
        csp = _CSP_BY_PATH.get(path, PAGE_CSP if path.startswith("/dashboard/")
                               else API_CSP).encode()

        async def send_with_headers(message: dict[str, Any]) -> None:
            if message["type"] == "http.response.start":
                names = {k.lower() for k, _ in message.get("headers", [])}
                extra = [(k, v) for k, v in _COMMON_HEADERS if k not in names]
                if b"content-security-policy" not in names:
                    extra.append((b"content-security-policy", csp))
                message = {**message, "headers": [*message.get("headers", []), *extra]}
            await send(message)

        host = _header(scope, b"host")
        given = None if host is None else host.decode("latin-1")
        if not host_allowed(given, self.hosts):
            # the name itself is not echoed (nothing of a Host header is ever reflected)
            await _respond(send_with_headers, 400,
                           "host: the Host header names no host of this service (loopback, "
                           "the bind address, CMRT_PUBLIC_URL's host or CMRT_ALLOWED_HOSTS); "
                           "a page whose name was rebound to this address is refused")
            return
        methods = self.allowed(scope)
        if methods and method == "OPTIONS":
            await _respond(send_with_headers, 204, None, {"allow": ", ".join(methods)})
            return
        if methods and method not in methods:
            await _respond(send_with_headers, 405,
                           f"method: {method} is not allowed on {path} "
                           f"(allowed: {', '.join(methods)})", {"allow": ", ".join(methods)})
            return
        if method not in SAFE_METHODS:
            refused = foreign_origin(scope, self.settings.public_url)
            if refused:
                await _respond(send_with_headers, 403,
                               f"origin: requests that change state from another origin are "
                               f"refused ({refused})")
                return
        if (needs_token(self.settings, method, path) and not self._token_ok(scope)
                and not (method in ("GET", "HEAD") and links.verify(
                    self.secret, path, scope.get("query_string", b"")))):
            await _respond(send_with_headers, 401,
                           "authorization: a valid 'Bearer <CMRT_API_TOKEN>' header is required",
                           {"www-authenticate": 'Bearer realm="cmrt"'})
            return
        if method == "HEAD":  # the GET route answers, without its body (RFC 9110 9.3.2)
            await self.asgi({**scope, "method": "GET"}, receive, _without_body(send_with_headers))
            return
        await self.asgi(scope, receive, send_with_headers)


def _origin_of(url: str) -> str:
    """`scheme://host[:port]` of an absolute URL, lower-cased (no path)."""
    parts = urlsplit(url.strip())
    return f"{parts.scheme}://{parts.netloc}".lower()


def foreign_origin(scope: Scope, public_url: str | None) -> str:
    """Why the request comes from a page of another origin ("" when it does not): its
    `Sec-Fetch-Site` says cross-site or same-site, or its `Origin` is neither
    `public_url`'s origin nor the request's own host (see the module docstring)."""
    site = _header(scope, b"sec-fetch-site")
    if site in (b"cross-site", b"same-site"):
        return f"Sec-Fetch-Site: {site.decode('latin-1')}"
    origin = _header(scope, b"origin")
    if origin is None:
        return ""
    given = origin.decode("latin-1")
    own = {_origin_of(public_url)} if public_url else set()
    host = _header(scope, b"host")
    if given != "null" and host is not None:
        own.add(f"{scope.get('scheme', 'http')}://{host.decode('latin-1')}")
    if given in own:
        return ""
    return f"Origin: {json.dumps(given[:100])}"


def _without_body(send: Send) -> Send:
    """`send` with every body chunk emptied (the headers, Content-Length included, kept)."""

    async def send_head(message: dict[str, Any]) -> None:
        if message["type"] == "http.response.body":
            message = {**message, "body": b""}
        await send(message)

    return send_head


def _header(scope: Scope, name: bytes) -> bytes | None:
    for k, v in scope.get("headers", []):
        if k == name:
            return v.strip().lower()
    return None


async def _respond(send: Send, status: int, detail: str | None,
                   headers: dict[str, str] | None = None) -> None:
    body = b"" if detail is None else json.dumps({"detail": detail}).encode()
    hdrs = [(k.encode(), v.encode()) for k, v in (headers or {}).items()]
    if detail is not None:
        hdrs.append((b"content-type", b"application/json"))
    hdrs.append((b"content-length", str(len(body)).encode()))
    await send({"type": "http.response.start", "status": status, "headers": hdrs})
    await send({"type": "http.response.body", "body": body})
