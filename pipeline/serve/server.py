"""`shaderball serve`: the HTTP side, on the standard library's ThreadingHTTPServer.

Why the standard library's server rather than uvicorn/starlette or aiohttp: the work is two
blocking threads (Mitsuba, torch) that an event loop would only hand off to; the rules below
are each a few lines on ThreadingHTTPServer, and a framework would need the same ones (its
Host and Origin middleware are opt-in lists too), plus a dependency in the lock. The
tests/test_serve_hold.py figures (64 connections at once, 16 worst-case uploads) hold on it.

Routes (JSON unless said):

    GET  /                    the page (page.html, in this package; nothing from the internet)
    GET  /api/info            what the server offers: network or not, ranges, presets, samples
    POST /api/view            {client, material, light, exposure, fresh} -> {generation, known, uploads}
                              (a change of exposure alone keeps the generation: the pictures
                              held are tone-mapped again, nothing renders again; ``fresh``: a
                              reloaded page's first view, what was held for the client dropped)
    POST /api/upload?client=ID&map=diffuse|specular|roughness|normal   body: PNG or EXR bytes
                              -> {map, texels, preview}: the map as its canvas shows it
    GET  /api/frame?client=ID&since=VERSION   long poll: the client's frame once it changes
                              (``known``: false when the server holds nothing of the client, see
                              pipeline.serve.workers: the page uploads its maps and view again; a
                              GET never makes a client, a POST of the page does)

Every refusal is a 4xx JSON ``{"ok": false, "error": "..."}`` the page shows; an unexpected
failure is a 500 with one line, never a traceback. A client that goes away mid-answer costs
the server nothing (BrokenPipeError and ConnectionResetError end that answer only).

What a request must be, checked before any route runs (:meth:`JsonHandler.refusal`):

- Each header the server reads (:data:`SINGLE_HEADERS`) comes once (400 otherwise): a second
  ``Host``, even after a good one, is how a request smuggled past a proxy's check looks.
- Its ``Host`` names this server (421 otherwise), against DNS rebinding: a page of another
  site whose name is pointed at this address sends its own name. Allowed: ``localhost``,
  ``127.0.0.1`` and ``[::1]``, the address bound, each with the port (without one only on
  port 80). Bound to every address (``--host 0.0.0.0`` or ``::``), the server also allows any
  IP literal and this machine's host names (``socket.gethostname()``, ``getfqdn()``): a
  rebinding attack sends a DNS name, never an IP literal.
- A request to the API (anything but the page, which any site may link to) is the page's
  own: where a browser sends ``Sec-Fetch-Site`` it is ``same-origin`` (or ``none``, typed by
  the user), and where an ``Origin`` comes it is ``http://`` + the Host header (403
  otherwise). So another site's ``<img src=/api/frame?...>`` is refused, and in any case a GET
  makes no client (pipeline.serve.workers): no other page can fill the server's client slots.
- A POST carries its body's type (415 otherwise): ``application/json`` for /api/view; for
  /api/upload ``image/png``, ``image/x-exr`` or ``application/octet-stream`` (the page sends
  the first two). Neither is a type a cross-site form may send, so a browser asks the server
  first (CORS preflight, refused: OPTIONS is a 405).
- Content-Length is ASCII digits (400 otherwise; 411 missing; 413 past the route's limit);
  the body arrives within :data:`BODY_STALL_S` of each read and :data:`BODY_DEADLINE_S` in
  all (408 then, and the connection closes), or a short body whose client hung up is a 400.
- HEAD answers wherever GET does, with GET's status and headers and never a body.

Every error answer closes its connection, so the bytes of a body not read are never read as
the next request. The listening socket queues :data:`LISTEN_BACKLOG` connections
(ThreadingHTTPServer's 5 reset a burst of a page's requests).

The transport (answers, the checks above, bounded reads) is pipeline.serve.transport; the
work behind the routes, pipeline.serve.workers.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import signal
import threading
import time
from dataclasses import dataclass
from http.server import ThreadingHTTPServer
from importlib import resources
from urllib.parse import urlsplit

from materials import SVBRDF_FAMILIES
from pipeline.fields import Checked, field
from pipeline.fields.rules import Bool, Int, Many, Optional, Path, Text
from pipeline.serve.materials import (
    DATASET_ALLOWED,
    MAX_UPLOAD_BYTES,
    TEXTURE_TEXELS,
    DatasetSamples,
    NotADataset,
    decode_upload,
    material_maps,
)
from pipeline.serve.pictures import png_data_url, texture_srgb8
from pipeline.serve.scenes import ENVIRONMENT_ALLOWED, OBJECT_ALLOWED, SceneFileRefused, open_scenes
from pipeline.serve.scope import training_scope
from pipeline.serve.transport import MAX_JSON_BYTES, PAGE_ROUTES, HostPolicy, JsonHandler, json_body
from pipeline.serve.view import (
    ALBEDO_PNG,
    CLOUDINESS_TURBIDITY,
    DatasetChoice,
    FrameRequest,
    RequestError,
    UploadRequest,
    api_defaults,
    api_ranges,
    environment_ranges,
    is_fresh,
    parse_view,
)
from pipeline.serve.workers import (
    PASS_TOTALS,
    PATH_RESOLUTION,
    Hub,
    NetworkRunner,
    PathTracer,
)
from pipeline.ui.interrupt import Stopped

log = logging.getLogger(__name__)
#: Connections the listening socket holds before they are accepted (a burst of 64 is served).
LISTEN_BACKLOG = 128
#: Uploads whose bodies are read and decoded at once, all clients together (each holds up to
#: MAX_UPLOAD_BYTES of body meanwhile; the decoded pixels have their own budget, materials.py).
UPLOADS_AT_ONCE = 8
#: Seconds an upload waits for its turn before it is refused (503): 16 worst-case uploads at
#: once take about 15 s here.
UPLOAD_WAIT_S = 120.0
#: Longest a /api/frame long poll waits, seconds.
FRAME_WAIT_S = 10.0
#: Seconds between two looks of the server loop (and of serve() while starting) at a Ctrl-C.
STOP_POLL_S = 0.1
#: Seconds serve(), once stopped, gives the path tracer and the network to end the call they are
#: in; a call still under way then (a Mitsuba render, a kernel compiling) is abandoned.
STOP_WAIT_S = 0.2
PORT_RANGE = (0, 65535)
#: Sun moves the benchmark times.
REPEATS_RANGE = (1, 100)
TRAIN_HINT = (
    "No network: start with --run RUN. `make serve-network` builds a dataset and trains one "
    "(under 15 minutes on 2 cores; docs/serve.md)."
)


class QuietServer(ThreadingHTTPServer):
    """socketserver prints a traceback for an error outside the handler's own answers: a client
    that resets or stalls its connection while its request is read. That ends the connection
    only; it is logged, not printed on the terminal the server owns."""

    daemon_threads = True
    request_queue_size = LISTEN_BACKLOG
    #: serve()'s :class:`Stopper`: the loop ends (StopServing) once it is asked.
    stopper = None

    def service_actions(self):
        if self.stopper is not None and self.stopper.asked:
            raise StopServing

    def server_bind(self):
        super().server_bind()
        self.upload_slots = threading.BoundedSemaphore(UPLOADS_AT_ONCE)
        self.hosts = HostPolicy.of(self.server_address[0], self.server_address[1])

    def handle_error(self, request, client_address):
        log.debug("connection from %s ended by an error", client_address, exc_info=True)


class Repeated(Many):
    """An option given any number of times (``--object A --object B``), none included."""

    def check(self, value):
        return () if isinstance(value, (list, tuple)) and not value else super().check(value)


class StopServing(Exception):
    """Raised by the server loop of :func:`serve` once Ctrl-C asked it to stop."""


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
    object: tuple[str, ...] = field(
        (),
        rule=Repeated(Path(OBJECT_ALLOWED, exists="file")),
        doc="A mesh file the page offers beside the built-in objects (repeat for more); checked at start.",
        metavar="PATH",
    )
    environment: tuple[str, ...] = field(
        (),
        rule=Repeated(Path(ENVIRONMENT_ALLOWED, exists="any")),
        doc="An HDR environment map (or a folder of them) the page may light with (repeat for more); checked at start.",
        metavar="PATH",
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


def open_dataset(options: ServeOptions) -> DatasetSamples | None:
    """The samples of ``options.dataset`` (None without one); refused naming ``dataset``."""
    if options.dataset is None:
        return None
    try:
        return DatasetSamples(options.dataset)
    except NotADataset as exc:
        raise ServeOptions.field_error("dataset", options.dataset, DATASET_ALLOWED, what=exc.what) from None


def open_offer(options: ServeOptions, dataset: DatasetSamples | None):
    """The objects and maps the page may pick (pipeline.serve.scenes); a file a gate refuses
    is refused naming its option (``object`` or ``environment``), the file and the reason."""
    try:
        return open_scenes(options.object, options.environment, dataset)
    except SceneFileRefused as exc:
        allowed = OBJECT_ALLOWED if exc.option == "object" else ENVIRONMENT_ALLOWED
        raise ServeOptions.field_error(exc.option, exc.path, allowed, what=exc.reason) from None


class App:
    """The server's state: the hub, the workers, the dataset picker and the network."""

    def __init__(self, options: ServeOptions, network=None, stored=None):
        """``network``: pipeline.neural.live.LiveNetwork or None; ``stored``: a callable giving
        the stored renders of a dataset root (pipeline.neural.stored.stored_renders) or None,
        then a dataset sample is shown without its stored render."""
        self.options = options
        self.network, self.stored = network, stored
        self.dataset = open_dataset(options)
        self.scenes = open_offer(options, self.dataset)
        config = getattr(network, "config", None)
        self.scope = training_scope(config, options.dataset) if network is not None else None
        net_res = network.resolution if network is not None else None
        path_res = PATH_RESOLUTION if net_res is None else net_res * max(1, round(PATH_RESOLUTION / net_res))
        self.hub = Hub(path_res, net_res)
        self.fatal = None
        self.tracer = PathTracer(self.hub, options.variant, on_fatal=self._fatal)
        self.runner = None
        self.httpd = None
        self.http_thread = None  # serve_in_thread's; serve() runs the loop in the main thread

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
            self.runner = NetworkRunner(self.hub, self.network, self.scope)
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
        self.http_thread = thread
        return thread

    def close(self, wait_s: float = 60.0) -> tuple[str, ...]:
        """Close the port and the hub (nothing is published from here), then wait up to
        ``wait_s`` for the path tracer and the network to end the call they are in; the names
        of those still in one are returned (abandoned: see :func:`serve`)."""
        if self.httpd is not None:
            if self.http_thread is not None and self.http_thread.is_alive():
                self.httpd.shutdown()  # waits for a running loop only: one never started would hang it
            self.httpd.server_close()
        self.hub.close()
        workers = [t for t in (self.tracer, self.runner) if t is not None and t.is_alive()]
        deadline = time.monotonic() + wait_s
        for thread in workers:
            thread.join(max(0.0, deadline - time.monotonic()))
        return tuple(t.name for t in workers if t.is_alive())

    def info(self) -> dict:
        return {
            "network": self.network.describe() if self.network is not None else None,
            # What the network learned from (objects, light source): the page warns outside it.
            "trained_on": self.scope.to_dict() if self.scope is not None else None,
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
            # The paint canvases' size, and what an 8-bit albedo PNG upload means (the page
            # converts its sRGB canvases to it before uploading).
            "texture_texels": TEXTURE_TEXELS,
            "albedo_png": ALBEDO_PNG,
            "samples": self.dataset.listing() if self.dataset is not None else [],
            **self.scenes.listing(),  # objects, environments, default_object
            "environment": environment_ranges(),  # a map's rotation and intensity: ranges, defaults
        }

    def view(self, doc) -> dict:
        client, view = parse_view(doc, self.scenes)
        known = self.hub.knows(client)  # False: a tab whose state was forgotten sends it again
        if is_fresh(doc):
            self.hub.start_afresh(client)  # a reloaded page: it holds none of what the server held
        uploads = self.hub.uploads(client)
        reference = None
        if isinstance(view.material, DatasetChoice) and self.dataset is not None and self.stored is not None:
            # The sample's stored render, shown beside path tracing (read once per material).
            reference = lambda: self.stored(self.dataset.root).reference(view.material.sample)  # noqa: E731
        generation = self.hub.submit(
            client, view, lambda: material_maps(view.material, self.dataset, uploads), reference
        )
        outside = self.scope.warning(view.object, view.light) if self.scope is not None else None
        return {
            "ok": True,
            "generation": generation,
            "known": known,
            "uploads": sorted(uploads),
            "network_outside": outside,
        }

    def upload(self, query: dict, body: bytes) -> dict:
        request = UploadRequest.from_doc(query)
        pixels = decode_upload(request.map, body)
        self.hub.store_upload(request.client, request.map, pixels)
        # The map as the page's canvas shows it (albedo sRGB-encoded): an EXR upload is drawn too.
        preview = png_data_url(texture_srgb8(request.map, pixels))
        return {"ok": True, "map": request.map, "texels": list(pixels.shape[:2]), "preview": preview}

    def frame(self, query: dict) -> dict:
        request = FrameRequest.from_doc(query)
        return self.hub.frame(request.client, int(request.since), FRAME_WAIT_S)


def page_bytes() -> bytes:
    return resources.files("pipeline.serve").joinpath("page.html").read_bytes()


#: The routes: what each answers, given the handler (its app, query and body).
GET_ROUTES = {
    "/api/info": lambda h: h.app.info(),
    "/api/frame": lambda h: h.app.frame(h.query()),
}
POST_ROUTES = {
    "/api/view": lambda h: h.app.view(json_body(h.body(MAX_JSON_BYTES))),
    "/api/upload": lambda h: h.upload(),
}


class Handler(JsonHandler):
    """The routes of one app (:func:`handler_for` sets ``app``)."""

    app: App

    def upload(self) -> dict:
        """/api/upload, its body read only once one of the server's upload slots is free."""
        query = self.query()
        if not self.server.upload_slots.acquire(timeout=UPLOAD_WAIT_S):
            raise RequestError(f"upload: {UPLOADS_AT_ONCE} uploads are under way; send it again shortly", 503)
        try:
            return self.app.upload(query, self.body(MAX_UPLOAD_BYTES))
        finally:
            self.server.upload_slots.release()

    def parse_request(self) -> bool:
        """http.server's, then the checks of :meth:`refusal` before any ``do_*`` runs."""
        if not super().parse_request():
            return False
        refused = self.refusal()
        if refused is not None:
            self._error(*refused)
            return False
        return True

    def do_GET(self):  # noqa: N802 - http.server's name; HEAD is the same, its body unsent (_send)
        route = urlsplit(self.path).path
        if route in PAGE_ROUTES:
            self._send(200, page_bytes(), "text/html; charset=utf-8")
        elif route in GET_ROUTES:
            self.answer(lambda: GET_ROUTES[route](self))
        elif route in POST_ROUTES:
            self._error(405, f"{route}: use POST")
        else:
            self._error(404, f"{route}: no such page; the page is at /")

    do_HEAD = do_GET  # noqa: N815

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

    do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _not_allowed  # noqa: N815


def handler_for(app: App) -> type[Handler]:
    """The request handler class of ``app``."""
    return type("Handler", (Handler,), {"app": app})


@dataclass
class ServeSummary:
    url: str
    stopped_by: str

    def lines(self) -> list[str]:
        return [f"stopped ({self.stopped_by}); served {self.url}"]


def serve(options: ServeOptions, network_loader=None, ready=None, stored=None) -> ServeSummary:
    """Run the server until Ctrl-C, then stop it and raise :class:`Stopped` (the CLI's exit code
    130 and its one line). ``network_loader``: a callable returning the network
    (pipeline.neural.live.LiveNetwork) or None; ``ready(lines)``: told the address once it listens;
    ``stored``: as :class:`App`'s.

    Ctrl-C never raises in the middle of the work: while serve() runs, SIGINT only asks the
    server to stop (:class:`Stopper`), and the main thread, which never waits on the work
    itself, stops it: start-up (the network's load, Mitsuba's and the G-buffers', in a thread
    of their own) is left where it is; the loop ends within :data:`STOP_POLL_S`; the port and
    the hub close, so nothing more is published; the path tracer and the network get
    :data:`STOP_WAIT_S` to end their call. A call still under way then (a Mitsuba render, which
    cannot be cut short, or a kernel compiling: seconds on a busy machine) is abandoned, not
    finished: the :class:`Stopped` raised names the threads left in one, and the process ends
    at once after its line (pipeline.ui.process), since interpreter shutdown beside a thread
    inside Mitsuba aborts the process ("terminate called without an active exception"). The
    Stopper's handler then stays in place, so a second Ctrl-C cannot start that shutdown
    either. Mitsuba puts its own SIGINT handler in place while it renders; it passes the signal
    on to the one it replaced, the Stopper's.
    """
    stopper = Stopper()
    with stopper.installed():
        started = stopper.unless_stopped(lambda: _started(options, network_loader, stored, stopper))
        if started is None:
            stopper.keep = True
            raise Stopped("stopped (Ctrl-C); served nothing (stopped while starting)", ("shaderball-start",))
        app, network = started
        try:
            if not stopper.asked:
                if ready is not None:
                    ready(_ready_lines(app, options, network))
                app.httpd.stopper = stopper
                app.httpd.serve_forever(poll_interval=STOP_POLL_S)
        except StopServing:
            pass  # Ctrl-C seen by the loop
        finally:
            left = app.close(STOP_WAIT_S)
            stopper.keep = bool(left)
        if stopper.asked or isinstance(app.fatal, KeyboardInterrupt):
            raise Stopped(f"stopped (Ctrl-C); served {app.url}", left)
    return ServeSummary(app.url, f"{type(app.fatal).__name__}: {app.fatal}")


def _started(options: ServeOptions, network_loader, stored, stopper: Stopper) -> tuple[App, object]:
    """The app, listening, and its network (serve()'s start-up, in a thread of its own)."""
    network = network_loader() if network_loader is not None else None
    app = App(options, network, stored)
    stopper.on_stop.append(app.hub.stop)
    try:
        app.start()
    except BaseException:
        app.close()
        raise
    if stopper.asked:  # serve() went on without this thread: nothing is left listening
        app.close()
    return app, network


def _ready_lines(app: App, options: ServeOptions, network) -> list[str]:
    lines = [
        f"serving {app.url} (Ctrl-C stops it)",
        "network: " + (f"{options.run} at {network.resolution} px" if network else "none; " + TRAIN_HINT),
    ]
    if not app.loopback:
        lines.append(f"--host {options.host}: other machines that reach this one can use the page")
    return lines


class Stopper:
    """SIGINT while :func:`serve` runs sets ``asked`` (and calls ``on_stop``: the hub's flag,
    which takes no lock), nothing else: no lock taken, no thread started in a signal handler
    (the main thread may hold either when the signal comes). The server loop sees it within its
    poll interval (:meth:`QuietServer.service_actions`), start-up within :data:`STOP_POLL_S`
    (:meth:`unless_stopped`). ``keep``: the handler stays in place once serve() ends (threads
    were left running; see serve())."""

    def __init__(self):
        self.asked = False
        self.keep = False
        self.on_stop: list = []

    def on_sigint(self, signum, frame) -> None:
        self.asked = True
        for stop in list(self.on_stop):
            stop()

    def unless_stopped(self, work):
        """``work()``'s result, run in a thread of its own so that a Ctrl-C meanwhile is answered
        at once: None then (the thread is left to itself). Its exception is raised here."""
        done, result = threading.Event(), {}

        def run():
            try:
                result["value"] = work()
            except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread
                result["error"] = exc
            finally:
                done.set()

        threading.Thread(target=run, name="shaderball-start", daemon=True).start()
        while not done.wait(STOP_POLL_S):
            if self.asked:
                return None
        if "error" in result:
            raise result["error"]
        return result["value"]

    @contextlib.contextmanager
    def installed(self):
        if threading.current_thread() is not threading.main_thread():
            yield  # signals reach the main thread only; a caller elsewhere stops the app itself
            return
        previous = signal.signal(signal.SIGINT, self.on_sigint)
        try:
            yield
        finally:
            if not self.keep:
                signal.signal(signal.SIGINT, previous)
