"""`shaderball serve`: the HTTP side, on the standard library's ThreadingHTTPServer.

Routes (JSON unless said):

    GET  /                    the page (page.html, in this package; nothing from the internet)
    GET  /api/info            what the server offers: network or not, ranges, presets, samples
    POST /api/view            {client, material, light, exposure} -> {generation}
    POST /api/upload?client=ID&map=diffuse|specular|roughness|normal   body: PNG or EXR bytes
    GET  /api/frame?client=ID&since=VERSION   long poll: the client's frame once it changes

Every refusal is a 4xx JSON ``{"ok": false, "error": "..."}`` the page shows; an unexpected
failure is a 500 with one line, never a traceback. A client that goes away mid-answer costs
the server nothing (BrokenPipeError and ConnectionResetError end that answer only).
"""

from __future__ import annotations

import ipaddress
import json
import logging
import threading
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlsplit

from materials import SVBRDF_FAMILIES
from pipeline.errors import USER_ERRORS
from pipeline.fields import Bool, Checked, FieldError, Int, Optional, Path, Text, field
from pipeline.serve.materials import (
    DATASET_ALLOWED,
    MAX_UPLOAD_BYTES,
    DatasetSamples,
    NotADataset,
    decode_upload,
    material_maps,
    too_large,
)
from pipeline.serve.view import (
    CLOUDINESS_TURBIDITY,
    FrameRequest,
    RequestError,
    UploadRequest,
    api_defaults,
    api_error,
    api_ranges,
    api_status,
    parse_view,
)
from pipeline.serve.work import PASS_TOTALS, PATH_RESOLUTION, Hub, NetworkRunner, PathTracer

log = logging.getLogger(__name__)

#: Largest JSON body of /api/view, bytes.
MAX_JSON_BYTES = 64 * 1024
#: Longest a /api/frame long poll waits, seconds.
FRAME_WAIT_S = 10.0
PORT_RANGE = (0, 65535)
#: Sun moves the benchmark times.
REPEATS_RANGE = (1, 100)
TRAIN_HINT = (
    "No network: start with --run RUN. `make serve-network` trains a small one on the smoke "
    "dataset in a few minutes (docs/serve.md)."
)


class QuietServer(ThreadingHTTPServer):
    """socketserver prints a traceback for an error outside the handler's own answers: a client
    that resets or stalls its connection while its request is read. That ends the connection
    only; it is logged, not printed on the terminal the server owns."""

    daemon_threads = True

    def handle_error(self, request, client_address):
        log.debug("connection from %s ended by an error", client_address, exc_info=True)


@dataclass(frozen=True)
class ServeOptions(Checked):
    """What `shaderball serve` is asked; each input declared once (pipeline.fields), checked
    when built."""

    run: str | None = field(
        None,
        rule=Optional(Path("a run folder", exists="folder"), default_text="none, a path-traced previewer"),
        doc="A training run folder: the network shown beside path tracing.",
        metavar="RUN",
    )
    checkpoint: str = field(
        "last",
        rule=Text(r".+", "last, best or a checkpoint file"),
        doc="{run}'s weights, as `shaderball infer --checkpoint`.",
        metavar="last|best|FILE",
    )
    dataset: str | None = field(
        None,
        rule=Optional(Path(DATASET_ALLOWED, exists="folder")),
        doc="A dataset folder or its publication, whose samples the page offers by id.",
        metavar="DIR|PUB",
    )
    host: str = field(
        "127.0.0.1",
        rule=Text(r"\S+", "an address to bind, such as 127.0.0.1"),
        doc="Address to bind; another than 127.0.0.1 lets other machines in.",
    )
    port: int = field(8765, rule=Int(*PORT_RANGE), doc="Port (0: any free one).")
    threads: int = field(0, rule=Int(0, 256), doc="torch threads for the network (0: torch's default).", unit="threads")
    benchmark: bool = field(
        False,
        rule=Bool(),
        doc="Print the network's time per frame and the first path-traced pass's time instead of serving.",
    )
    repeats: int = field(
        9, rule=Int(*REPEATS_RANGE), doc="With {benchmark}: how many sun moves are timed.", unit="sun moves"
    )
    #: The path tracer's Mitsuba variant (not a command-line option).
    variant: str = "llvm"

    def __post_init__(self):
        self.check_fields()

    def check(self) -> ServeOptions:
        """Self (checked when built); for callers that check explicitly."""
        return self


def open_dataset(options: ServeOptions) -> DatasetSamples | None:
    """The samples of ``options.dataset`` (None without one); refused naming ``dataset``."""
    if options.dataset is None:
        return None
    try:
        return DatasetSamples(options.dataset)
    except NotADataset as exc:
        raise ServeOptions.field_error("dataset", options.dataset, DATASET_ALLOWED, what=exc.what) from None


class App:
    """The server's state: the hub, the workers, the dataset picker and the network."""

    def __init__(self, options: ServeOptions, network=None):
        self.options = options.check()
        self.network = network
        self.dataset = open_dataset(options)
        net_res = network.resolution if network is not None else None
        path_res = PATH_RESOLUTION if net_res is None else net_res * max(1, round(PATH_RESOLUTION / net_res))
        self.hub = Hub(path_res, net_res)
        self.fatal = None
        self.tracer = PathTracer(self.hub, options.variant, on_fatal=self._fatal)
        self.runner = None
        self.httpd = None

    def _fatal(self, exc: BaseException) -> None:
        self.fatal = exc
        if self.httpd is not None:
            threading.Thread(target=self.httpd.shutdown, daemon=True).start()

    def start(self) -> App:
        """Load Mitsuba and the G-buffers (in the path tracer's thread), then bind the port."""
        self.tracer.start()
        self.tracer.ready.wait()
        if self.tracer.failure is not None:
            raise self.tracer.failure
        if self.network is not None:
            self.runner = NetworkRunner(self.hub, self.network, lambda: self.tracer.network_gbuffer)
            self.runner.start()
        try:
            self.httpd = QuietServer((self.options.host, self.options.port), handler_for(self))
        except OSError as exc:
            host, port = self.options.host, self.options.port
            raise ServeOptions.field_error(
                "port", port, "a free port (0: any free one)", what=f"cannot listen on {host}:{port} ({exc.strerror})"
            ) from None
        return self

    @property
    def loopback(self) -> bool:
        return ipaddress.ip_address(self.httpd.server_address[0]).is_loopback

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host}:{port}/"

    def serve_in_thread(self) -> threading.Thread:
        thread = threading.Thread(target=self.httpd.serve_forever, name="shaderball-http", daemon=True)
        thread.start()
        return thread

    def close(self) -> None:
        if self.httpd is not None:
            self.httpd.shutdown()
            self.httpd.server_close()
        self.hub.close()
        for thread in (self.tracer, self.runner):
            if thread is not None and thread.is_alive():
                thread.join(60)  # the pass under way ends; Mitsuba is not left mid-render at exit

    def info(self) -> dict:
        return {
            "network": self.network.describe() if self.network is not None else None,
            "train_hint": None if self.network is not None else TRAIN_HINT,
            "path_resolution": self.hub.path_resolution,
            "passes_spp": list(PASS_TOTALS),
            "families": list(SVBRDF_FAMILIES),
            # Every number the page sends, [lo, hi] as /api/view checks it, and its default:
            # the page's sliders are set from these (page.html holds no range of its own).
            "ranges": api_ranges(),
            "defaults": api_defaults(),
            "cloudiness_turbidity": list(CLOUDINESS_TURBIDITY),
            "max_upload_bytes": MAX_UPLOAD_BYTES,
            "samples": self.dataset.listing() if self.dataset is not None else [],
        }

    def view(self, doc) -> dict:
        client, view = parse_view(doc)
        uploads = self.hub.uploads(client)
        generation = self.hub.submit(client, view, lambda: material_maps(view.material, self.dataset, uploads))
        return {"ok": True, "generation": generation}

    def upload(self, query: dict, body: bytes) -> dict:
        request = UploadRequest.from_doc(query)
        pixels = decode_upload(request.map, body)
        self.hub.store_upload(request.client, request.map, pixels)
        return {"ok": True, "map": request.map, "texels": list(pixels.shape[:2])}

    def frame(self, query: dict) -> dict:
        request = FrameRequest.from_doc(query)
        return self.hub.frame(request.client, int(request.since), FRAME_WAIT_S)


def page_bytes() -> bytes:
    return resources.files("pipeline.serve").joinpath("page.html").read_bytes()


class JsonHandler(BaseHTTPRequestHandler):
    """The transport: answers as JSON (refusals too, http.server's own included), bodies and
    queries read within bounds, a client that goes away costing nothing."""

    server_version = "shaderball-serve"
    protocol_version = "HTTP/1.1"
    #: Seconds a socket read or write may stall (a client that sends half a body lets go then).
    timeout = 60

    def send_error(self, code, message=None, explain=None):
        """http.server's own refusals (a malformed request line, a header too long) as JSON too."""
        self.close_connection = True
        self._error(int(code), f"{int(code)} {message or HTTPStatus(int(code)).phrase}")

    def log_message(self, format, *args):  # noqa: A002 - the library's name
        pass  # the library never prints; a request log is not wanted on the terminal

    def _send(self, status: int, body: bytes, content_type: str) -> None:
        try:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):
            self.close_connection = True  # the client went away: its answer is dropped

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
        if length is None or not length.isdigit():
            raise RequestError("Content-Length: missing or not a number; send the body with its length", 411)
        if int(length) > limit:
            self.close_connection = True  # the body is not read: the connection cannot be reused
            raise too_large("body", f"{int(length)} bytes", f"at most {limit} bytes")
        return self.rfile.read(int(length))

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


#: The routes: what each answers, given the handler (its app, query and body).
GET_ROUTES = {
    "/api/info": lambda h: h.app.info(),
    "/api/frame": lambda h: h.app.frame(h.query()),
}
POST_ROUTES = {
    "/api/view": lambda h: h.app.view(_json_body(h.body(MAX_JSON_BYTES))),
    "/api/upload": lambda h: h.app.upload(h.query(), h.body(MAX_UPLOAD_BYTES)),
}
PAGE_ROUTES = ("/", "/index.html")


class Handler(JsonHandler):
    """The routes of one app (:func:`handler_for` sets ``app``)."""

    app: App

    def do_GET(self):  # noqa: N802 - http.server's name
        route = urlsplit(self.path).path
        if route in PAGE_ROUTES:
            self._send(200, page_bytes(), "text/html; charset=utf-8")
        elif route in GET_ROUTES:
            self.answer(lambda: GET_ROUTES[route](self))
        elif route in POST_ROUTES:
            self._error(405, f"{route}: use POST")
        else:
            self._error(404, f"{route}: no such page; the page is at /")

    def do_POST(self):  # noqa: N802
        route = urlsplit(self.path).path
        if route in POST_ROUTES:
            self.answer(lambda: POST_ROUTES[route](self))
        elif route in GET_ROUTES or route in PAGE_ROUTES:
            self._error(405, f"{route}: use GET")
        else:
            self._error(404, f"{route}: no such page; the page is at /")

    def _not_allowed(self):
        self._error(405, f"{self.command}: not allowed; use GET or POST")

    do_PUT = do_DELETE = do_PATCH = do_HEAD = do_OPTIONS = _not_allowed  # noqa: N815


def handler_for(app: App) -> type[Handler]:
    """The request handler class of ``app``."""
    return type("Handler", (Handler,), {"app": app})


def _json_body(body: bytes):
    try:
        return json.loads(body.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise RequestError(f"body: not JSON ({type(exc).__name__}: {str(exc)[:80]})", 400) from None


@dataclass
class ServeSummary:
    url: str
    stopped_by: str

    def lines(self) -> list[str]:
        return [f"stopped ({self.stopped_by}); served {self.url}"]


def serve(options: ServeOptions, network_loader=None, ready=None) -> ServeSummary:
    """Run the server until Ctrl-C. ``network_loader``: a callable returning the network
    (pipeline.neural.live.LiveNetwork) or None; ``ready(lines)``: told the address once it listens."""
    network = network_loader() if network_loader is not None else None
    app = App(options, network)
    try:
        app.start()
        if ready is not None:
            ready(
                [
                    f"serving {app.url} (Ctrl-C stops it)",
                    "network: " + (f"{options.run} at {network.resolution} px" if network else "none; " + TRAIN_HINT),
                ]
                + (
                    []
                    if app.loopback
                    else [f"--host {options.host}: other machines that reach this one can use the page"]
                )
            )
        app.httpd.serve_forever()
    except KeyboardInterrupt:
        pass  # Ctrl-C, while starting or serving: the summary's one line says so
    finally:
        app.close()
    return ServeSummary(app.url if app.httpd is not None else "nothing (stopped while starting)", "Ctrl-C")
