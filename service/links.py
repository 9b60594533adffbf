"""Signed, short-lived links to the replay pages and a job's motion files, for a browser that
cannot send the token.

With `CMRT_API_TOKEN` set and public reads off, every data read needs `Authorization: Bearer`;
a link the dashboard hands to the browser (`<a href="/jobs/{id}/replay">`) cannot carry a
header, so it would answer 401. `POST /links` (which needs the token like every write) mints
`<path>?expires=<unix s>&signature=<hex>`: an HMAC-SHA256, keyed by the API token, of the path
and the whole query but the signature (every parameter, sorted), so a parameter added to or
changed in a signed link (`&compare=false`) voids it. The HTTP edge (`service.security`) lets a
GET or HEAD of a replay page through with a valid, unexpired signature for exactly that path
and query. Links are minted only for a job or library CMRT that exists (404 otherwise). A link
lives `LINK_SECONDS`; changing the token revokes every link. Only the replay pages and a job's
motion downloads (`/jobs/{id}/motion.bvh`, `.csv`) are signable (`SIGNABLE`): they are what a
browser opens by following a link; the JSON endpoints keep needing the header.
"""

from __future__ import annotations

import hashlib
import hmac
import re
import time
from urllib.parse import parse_qsl, urlencode

#: How long a signed link stays valid, in seconds.
LINK_SECONDS = 900
#: The paths a link may be signed for: the replay pages of a job and of a library CMRT, and a
#: job's motion files.
SIGNABLE = re.compile(r"/(?:jobs|cmrts)/[A-Za-z0-9._~-]{1,64}/replay"
                      r"|/jobs/[A-Za-z0-9._~-]{1,64}/motion\.(?:bvh|csv)")


def signature(token: str, path: str, params: list[tuple[str, str]]) -> str:
    """The hex HMAC-SHA256 under the key `token` of `path` and the query parameters `params`
    (every one but `signature`; their order does not matter)."""
    msg = f"{path}\n{urlencode(sorted(params))}".encode()
    return hmac.new(token.encode(), msg, hashlib.sha256).hexdigest()


def sign(token: str, path: str, now: float | None = None) -> tuple[str, int]:
    """The signed link to `path` (a `SIGNABLE` path) and its expiry (unix seconds)."""
    expires = int(now if now is not None else time.time()) + LINK_SECONDS
    params = [("expires", str(expires))]
    query = urlencode([*params, ("signature", signature(token, path, params))])
    return f"{path}?{query}", expires


def verify(token: str, path: str, query_string: bytes | str, now: float | None = None) -> bool:
    """Whether the query string carries a valid, unexpired signature for `path` and every
    other parameter of the query."""
    if not token or not SIGNABLE.fullmatch(path):
        return False
    if isinstance(query_string, bytes):
        query_string = query_string.decode("latin-1")
    pairs = parse_qsl(query_string, keep_blank_values=True)
    sig = [v for k, v in pairs if k == "signature"]
    params = [(k, v) for k, v in pairs if k != "signature"]
    exp = [v for k, v in params if k == "expires"]
    if len(exp) != 1 or len(sig) != 1 or not exp[0].isdigit() or len(exp[0]) > 15:
        return False
    if int(exp[0]) < (now if now is not None else time.time()):
        return False
    return hmac.compare_digest(sig[0].encode(), signature(token, path, params).encode())
