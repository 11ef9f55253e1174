"""The HTTP transport of `shaderball serve`: :class:`JsonHandler` answers as JSON (refusals
too, http.server's own included), checks each request before its route runs (a header sent
twice, a ``Host`` that does not name the server (:class:`HostPolicy`), another site's request,
a POST's body type: pipeline.serve.server's docstring says why), and reads bodies and queries
within bounds, a client that goes away costing nothing."""

from __future__ import annotations

import ipaddress
import json
import re
import socket
import time
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler
from urllib.parse import parse_qs, urlsplit

from pipeline.errors import USER_ERRORS
from pipeline.fields import FieldError
from pipeline.serve.materials import too_large
from pipeline.serve.view import RequestError, api_error, api_status

#: Largest JSON body of /api/view, bytes.
MAX_JSON_BYTES = 64 * 1024
#: Seconds a connection may wait for its next request, or stall while its answer is written.
CONNECTION_IDLE_S = 60
#: Seconds a request body may stall between two reads before it is refused (408).
BODY_STALL_S = 10.0
#: Seconds a whole request body may take (8 MB in 60 s: 140 kB/s), however it trickles.
BODY_DEADLINE_S = 60.0
#: The body types each POST route takes (the media type, parameters such as charset aside).
POST_TYPES = {
    "/api/view": ("application/json",),
    "/api/upload": ("image/png", "image/x-exr", "application/octet-stream"),
}
#: Content-Length as it must be spelled: ASCII digits (str.isdigit also takes "²").
CONTENT_LENGTH = re.compile(r"[0-9]{1,19}")
#: Headers the server reads that a request may carry once only (a second Host, even after a
#: good one, is how a request smuggled past a proxy or a Host check looks).
SINGLE_HEADERS = ("Host", "Content-Length", "Content-Type", "Transfer-Encoding", "Origin", "Sec-Fetch-Site")
#: ``Sec-Fetch-Site`` values of a request the page itself makes, or a user types (browsers send
#: the header; "same-site" is another port of this host: another origin).
OWN_FETCH_SITES = ("same-origin", "none")
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "[::1]")


@dataclass(frozen=True)
class HostPolicy:
    """Which ``Host`` headers name this server (module docstring): ``names`` with the port,
    and with ``any_ip`` any IP literal too."""

    names: frozenset[str]
    port: int
    any_ip: bool

    @classmethod
    def of(cls, bound: str, port: int) -> HostPolicy:
        address = ipaddress.ip_address(bound)
        names = {*LOOPBACK_NAMES, f"[{bound}]" if address.version == 6 else bound}
        if address.is_unspecified:
            names |= {socket.gethostname().lower(), socket.getfqdn().lower()}
        return cls(frozenset(names), port, address.is_unspecified)

    def allows(self, host: str | None) -> bool:
        if not host:
            return False
        host = host.strip().lower()
        name, port = host.rsplit(":", 1) if host.rpartition(":")[0] and not host.endswith("]") else (host, "80")
        if port != str(self.port):
            return False
        if name in self.names:
            return True
        return self.any_ip and _ip_literal(name)

    def spelled(self) -> str:
        named = " or ".join(f"{n}:{self.port}" for n in sorted(self.names))
        return named + (f" (or any IP literal with :{self.port})" if self.any_ip else "")


def _ip_literal(name: str) -> bool:
    try:
        ipaddress.ip_address(name[1:-1] if name.startswith("[") and name.endswith("]") else name)
    except ValueError:
        return False
    return True


class JsonHandler(BaseHTTPRequestHandler):
    """The transport: answers as JSON (refusals too, http.server's own included), bodies and
    queries read within bounds, a client that goes away costing nothing."""

    server_version = "shaderball-serve"
    protocol_version = "HTTP/1.1"
    #: Seconds a socket read or write may stall (a request body: BODY_STALL_S).
    timeout = CONNECTION_IDLE_S

    def send_error(self, code, message=None, explain=None):
        """http.server's own refusals (a malformed request line, a header too long) as JSON too."""
        self.close_connection = True
        self._error(int(code), f"{int(code)} {message or HTTPStatus(int(code)).phrase}")

    def log_message(self, format, *args):  # noqa: A002 - the library's name
        pass  # the library never prints; a request log is not wanted on the terminal

    def _send(self, status: int, body: bytes, content_type: str) -> None:
        if status >= 400:
            self.close_connection = True  # a body not read is never taken for the next request
        try:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            if self.close_connection:
                self.send_header("Connection", "close")
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            self.close_connection = True  # the client went away: its answer is dropped

    def refusal(self) -> tuple[int, str] | None:
        """(status, message) of a request refused before its route runs, or None (module
        docstring: a header sent twice, Host, another site's request, a POST's Content-Type)."""
        for name in SINGLE_HEADERS:
            count = len(self.headers.get_all(name) or ())
            if count > 1:
                return 400, f"{name}: sent {count} times; send it once"
        host = self.headers.get("Host")
        hosts: HostPolicy = self.server.hosts
        if not hosts.allows(host):
            return 421, f"Host: {_shown(host)} is not allowed; {hosts.spelled()}"
        route = urlsplit(self.path).path
        if route not in PAGE_ROUTES:  # the page itself may be linked to from anywhere; its API not
            refused = _foreign(self.headers.get("Sec-Fetch-Site"), self.headers.get("Origin"), host)
            if refused is not None:
                return 403, refused
        if self.command != "POST":
            return None
        kind = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        allowed = POST_TYPES.get(route)
        if allowed is not None and kind not in allowed:
            return 415, f"Content-Type: {_shown(kind or None)} is not allowed; {' or '.join(allowed)}"
        return None

    def _json(self, status: int, doc: dict) -> None:
        self._send(status, json.dumps(doc).encode(), "application/json")

    def _error(self, status: int, message: str) -> None:
        self._json(status, {"ok": False, "error": message})

    def query(self) -> dict:
        try:
            pairs = parse_qs(urlsplit(self.path).query, keep_blank_values=True, max_num_fields=8)
        except ValueError:
            raise RequestError("query: more than 8 fields; allowed: client, map, since", 400) from None
        return {k: v[-1] for k, v in pairs.items()}

    def body(self, limit: int) -> bytes:
        length = self.headers.get("Content-Length")
        if length is None or "Transfer-Encoding" in self.headers:
            raise RequestError("Content-Length: missing; send the body with its length (no chunked encoding)", 411)
        if not CONTENT_LENGTH.fullmatch(length.strip()):
            raise RequestError(f"Content-Length: {_shown(length)} is not allowed; a number of bytes", 400)
        if int(length) > limit:
            raise too_large("body", f"{int(length)} bytes", f"at most {limit} bytes")
        return self._read_exactly(int(length))

    def _read_exactly(self, size: int) -> bytes:
        """``size`` bytes of body, each read within BODY_STALL_S and all within BODY_DEADLINE_S:
        408 past them, 400 when the client hangs up first."""
        deadline, parts, got = time.monotonic() + BODY_DEADLINE_S, [], 0
        try:
            while got < size:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError
                self.connection.settimeout(min(BODY_STALL_S, left))
                part = self.rfile.read1(min(size - got, 1 << 16))
                if not part:
                    raise RequestError(f"body: {got} of its {size} bytes came before the connection closed", 400)
                parts.append(part)
                got += len(part)
        except TimeoutError:
            raise RequestError(
                f"body: {got} of its {size} bytes came; each read may stall {BODY_STALL_S:g} s, "
                f"the whole body take {BODY_DEADLINE_S:g} s",
                408,
            ) from None
        finally:
            self.connection.settimeout(self.timeout)
        return b"".join(parts)

    def answer(self, work) -> None:
        """``work()``'s document, or its refusal as a 4xx (a field as the JSON spells it), or
        an unexpected failure as a 500 of one line."""
        try:
            self._json(200, work())
        except RequestError as exc:
            self._error(exc.status, str(exc))
        except FieldError as exc:
            self._error(api_status(exc), str(api_error(exc)))
        except USER_ERRORS as exc:
            self._error(400, str(exc))
        except (BrokenPipeError, ConnectionResetError):
            self.close_connection = True
        except Exception as exc:  # noqa: BLE001 - one line to the page, never a traceback
            self._error(500, f"internal error: {type(exc).__name__}: {exc}")


PAGE_ROUTES = ("/", "/index.html")


def _foreign(site: str | None, origin: str | None, host: str) -> str | None:
    """Why an API request is another site's (the browser's ``Sec-Fetch-Site``, or an
    ``Origin`` not this server's), or None. A browser sends either where it matters; a client
    that sends neither (curl, the benchmark) is no web page."""
    if site is not None and site.strip().lower() not in OWN_FETCH_SITES:
        return f"Sec-Fetch-Site: {_shown(site)} is not allowed; only this server's own page (same-origin) uses its API"
    if origin is not None and origin.strip().lower() != "http://" + host.strip().lower():
        return f"Origin: {_shown(origin)} is not allowed; this page's own, http://{host.strip()}"
    return None


def _shown(value: str | None) -> str:
    """A header's value as a refusal quotes it: bounded, printable."""
    return "missing" if value is None else ascii(value[:80])


def json_body(body: bytes):
    try:
        return json.loads(body.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise RequestError(f"body: not JSON ({type(exc).__name__}: {str(exc)[:80]})", 400) from None
