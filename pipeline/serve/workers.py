"""The server's workers: one Mitsuba thread, one network thread, fed by latest-wins slots.

Each client (a browser tab) has a generation counter. A new view bumps it and replaces the
client's pending jobs; a job whose generation is no longer the client's is dropped before it
starts, and its result is dropped if the generation moved while it ran. Path tracing is
progressive: passes bringing the total to 1, 4, 16, 64 spp, each a separate job checked
against the current generation before it starts, so a slider drag cancels within one pass.

Mitsuba's variant is process-global and not every path of it is thread-safe, so every Mitsuba
call (G-buffers, scene loads, renders) runs in :class:`PathTracer`'s one thread; the network
runs on torch in :class:`NetworkRunner`'s thread and touches no Mitsuba.

A client's life. A client is made only by a POST of the page (a view or an upload: a request
no other site can make, pipeline.serve.server); a GET (a frame poll, which any page's
``<img>`` can send) never makes one. Every request of a client marks it seen. An open tab
long-polls /api/frame at most every 10 s; a reloaded tab keeps its client id (the page keeps
it in sessionStorage) and its first view is ``fresh``: what the server held for it is
dropped. A client with no request for :data:`IDLE_S` (10 minutes: a closed tab, a machine
asleep) is forgotten, its uploads and view with it, when room is needed; with
:data:`MAX_CLIENTS` held, a new client takes the place of the one idle longest, so a new tab
is never refused. A client with no request for :data:`ABANDONED_S` has its path-tracing job
parked, not rendered (a closed tab keeps no render time); its next request puts the job back
in line.

A tab whose state was forgotten (or a server started again) is told so: the answers of
/api/frame and /api/view carry ``"known": false`` when the server held nothing of that client
before the request (a frame poll then answers at once), and /api/view's answer lists the
``uploads`` it holds. The page, on ``known: false``, uploads again every map it had uploaded
and posts its view again. The uploads of all clients together are bounded by
:data:`MAX_STORED_UPLOAD_BYTES` (4 maps of each of MAX_CLIENTS clients).

Objects. A view names the object it shows (pipeline.serve.scenes). The path tracer builds an
object and its G-buffers (:class:`Stage`) the first time a view shows it, in its own thread
(the G-buffers are Mitsuba's), and keeps it; the hub holds every stage made, so the maps
strip and the network (which waits for the stage its view needs) use the object's G-buffers.
The shaderball's stage is made at start.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from geometry.objects import build_object, object_camera
from pipeline.errors import USER_ERRORS
from pipeline.image.tonemap import hdr_to_srgb8
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.lights import is_environment
from pipeline.render.mitsuba_env import load_mitsuba, resolve_variant
from pipeline.render.raster import project_material
from pipeline.render.renderer import MaterialScene, PassSum, RenderSettings, pass_seed, relative_error
from pipeline.serve.materials import TEXTURE_TEXELS
from pipeline.serve.pictures import (  # noqa: F401 - texture_srgb8, noise_psnr_db: imported from here too
    difference,
    maps_strip,
    noise_psnr_db,
    png_data_url,
    texture_srgb8,
    unbiased_variance,
)
from pipeline.serve.view import DEFAULT_CHOICE, MAP_NAMES, RequestError, View

#: Total spp after each progressive pass; the pass sizes are the differences.
PASS_TOTALS = (1, 4, 16, 64)
#: A pass is rendered in chunks of at most this many spp, the generation checked before each,
#: so a new view waits for one chunk (not a 48 spp pass) before its first pass starts.
CHUNK_SPP = 4
#: Most clients (tabs) held at once; a new one past it takes the place of the one idle longest.
MAX_CLIENTS = 64
#: Seconds without a request after which a client is forgotten (its view and uploads).
IDLE_S = 600.0
#: Seconds without a request after which a client's path-tracing job is parked, not rendered.
ABANDONED_S = 30.0
#: Bytes of decoded uploads all clients hold together: every map of every client, float32 RGB.
MAX_STORED_UPLOAD_BYTES = MAX_CLIENTS * len(MAP_NAMES) * TEXTURE_TEXELS * TEXTURE_TEXELS * 3 * 4
#: Path-traced frames are this many pixels a side unless the network's resolution asks for more.
PATH_RESOLUTION = 128


@dataclass
class Job:
    client: str
    generation: int
    view: View
    maps: object  # materials.MaterialMaps, the same object for every job of one material
    index: int = 0  # the progressive pass
    chunk: int = 0  # chunks rendered so far (each its own seed)
    acc: PassSum = field(default_factory=PassSum)
    started: float = field(default_factory=time.perf_counter)
    pass_started: float | None = None


class LatestSlots:
    """At most one pending job per client; a new one replaces the old (latest wins). Clients
    take turns: :meth:`take` returns the job waiting longest."""

    def __init__(self):
        self.jobs: OrderedDict[str, Job] = OrderedDict()
        self.cond = threading.Condition()
        self.closed = False

    def put(self, job: Job, replace: bool = True) -> None:
        with self.cond:
            if job.client in self.jobs and not replace:
                return
            self.jobs.pop(job.client, None)
            self.jobs[job.client] = job
            self.cond.notify()

    def take(self) -> Job | None:
        with self.cond:
            while not self.jobs and not self.closed:
                self.cond.wait()
            if self.closed:
                return None
            return self.jobs.popitem(last=False)[1]

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()


@dataclass
class Client:
    generation: int = 0
    version: int = 0
    view: View | None = None
    material_key: tuple | None = None
    maps: object = None
    uploads: dict = field(default_factory=dict)
    frame: dict = field(default_factory=dict)
    network_hdr: np.ndarray | None = None
    path_hdr: np.ndarray | None = None
    path_variance: np.ndarray | None = None
    reference_hdr: np.ndarray | None = None  # a dataset sample's stored render, shown as a reference
    maps_object: str | None = None  # the object the frame's maps strip was projected on
    seen: float = 0.0  # the hub's clock at the client's last request


class Hub:
    """Every client's generation, pending jobs and latest frame; what the HTTP handlers call."""

    def __init__(self, path_resolution: int, network_resolution: int | None, clock=time.monotonic):
        self.lock = threading.Condition()
        self.clients: OrderedDict[str, Client] = OrderedDict()
        self.parked: dict[str, Job] = {}  # path-tracing jobs of abandoned clients, by client
        self.clock = clock  # seconds, monotonic (a test's own clock moves a client's idle time)
        self.path_slots, self.network_slots = LatestSlots(), LatestSlots()
        self.path_resolution, self.network_resolution = path_resolution, network_resolution
        self.screen_gbuffer = None  # the shaderball's G-buffer at the path tracer's resolution, once loaded
        self.stages: dict[str, Stage | BaseException] = {}  # by object name: made, or why not
        self.generations = itertools.count(1)
        self.stopped = False  # set once the server stops: nothing is published from then on

    def client(self, client_id: str) -> Client:
        """The client's state, seen now, made if the hub holds none (only a POST of the page
        makes one: module docstring; the one idle longest gives way when MAX_CLIENTS are held).
        Caller holds the lock."""
        client = self.seen(client_id)
        if client is None:
            self._make_room(self.clock())
            client = self.clients[client_id] = Client(seen=self.clock())
        return client

    def seen(self, client_id: str) -> Client | None:
        """The client's state marked seen now, its parked job back in line; None where the hub
        holds none (nothing is made). Caller holds the lock."""
        client = self.clients.get(client_id)
        if client is None:
            return None
        client.seen = self.clock()
        self.clients.move_to_end(client_id)  # the first is the one idle longest
        parked = self.parked.pop(client_id, None)
        if parked is not None:
            self.path_slots.put(parked, replace=False)  # a newer view of the client's, if any, stays
        return client

    def _make_room(self, now: float) -> None:
        """Forget the clients idle past IDLE_S, then the one idle longest while MAX_CLIENTS are held."""
        for client_id in [k for k, c in self.clients.items() if now - c.seen > IDLE_S]:
            self.forget(client_id)
        while len(self.clients) >= MAX_CLIENTS:
            self.forget(next(iter(self.clients)))

    def forget(self, client_id: str) -> None:
        """Drop the client's state (its next request is told ``known: false``). Caller holds the lock."""
        self.clients.pop(client_id, None)
        self.parked.pop(client_id, None)
        self.lock.notify_all()  # its long poll, if any, answers now

    def start_afresh(self, client_id: str) -> None:
        """A reloaded page's first view: what the hub held for the client (its uploads, maps,
        view and pictures) is dropped; a job of it under way is stale from now (a new generation)."""
        with self.lock:
            client = self.clients.get(client_id)
            if client is not None:
                generation = next(self.generations)
                self.clients[client_id] = Client(generation=generation, version=client.version, seen=client.seen)
                self.parked.pop(client_id, None)

    def knows(self, client_id: str) -> bool:
        """Whether the hub holds the client's state (seen, not forgotten); marks nothing."""
        with self.lock:
            return client_id in self.clients

    def park_if_abandoned(self, job: Job) -> bool:
        """True when ``job`` is not to be rendered now: its client is gone, or has made no
        request for ABANDONED_S (then the job is parked until the client's next request)."""
        with self.lock:
            client = self.clients.get(job.client)
            if client is None:
                return True
            if self.clock() - client.seen <= ABANDONED_S:
                return False
            self.parked[job.client] = job
            return True

    def uploads(self, client_id: str) -> dict:
        with self.lock:
            return dict(self.client(client_id).uploads)

    def store_upload(self, client_id: str, name: str, pixels: np.ndarray) -> None:
        with self.lock:
            client = self.client(client_id)
            held = sum(
                p.nbytes for c in self.clients.values() for k, p in c.uploads.items() if c is not client or k != name
            )
            if held + pixels.nbytes > MAX_STORED_UPLOAD_BYTES:
                raise RequestError(f"upload: the server holds {held} bytes of uploads, its most; try again later", 503)
            client.uploads[name] = pixels
            client.material_key = None  # the maps changed: next view makes them again

    def submit(self, client_id: str, view: View, make_maps, make_reference=None) -> int:
        """A new view: the client's generation moves on, its pending jobs are replaced. A view
        that differs from the client's only in its exposure renders nothing: the pictures held
        (linear HDR) are tone-mapped again at the new exposure, in the same generation, so
        path tracing goes on from the spp it has. ``make_reference``: (HDR, doc) of a stored
        render to show beside path tracing (a dataset sample's), or None; made with the maps."""
        key = view.material_key()
        with self.lock:
            client = self.client(client_id)
            if _same_scene(client, view, key):
                client.view = view
                self._show(client)
                self._changed(client)
                return client.generation
            same = client.material_key == key and client.maps is not None
            maps = client.maps if same else None
        reference = None
        if maps is None:
            maps = make_maps()  # may raise RequestError: nothing changes then
            reference = make_reference() if make_reference is not None else None
        with self.lock:
            client = self.client(client_id)
            if client.material_key != key or client.maps is None:
                client.material_key, client.maps = key, maps
                client.frame.pop("maps", None)
                client.reference_hdr, doc = reference or (None, None)
                client.frame.pop("reference", None)
                if doc is not None:
                    client.frame["reference"] = doc
            client.generation = next(self.generations)  # never reused, even by a forgotten client's id
            client.view = view
            client.network_hdr = client.path_hdr = client.path_variance = None
            for part in ("network", "path", "diff", "error"):
                client.frame.pop(part, None)
            if client.maps_object != view.object.name:
                client.frame.pop("maps", None)
            self._show_maps(client, view.object.name)
            self._show(client)
            self._changed(client)
            job = Job(client_id, client.generation, view, client.maps)
        self.path_slots.put(job)
        if self.network_resolution is not None:
            self.network_slots.put(Job(client_id, job.generation, view, job.maps))
        return job.generation

    def _show_maps(self, client: Client, name: str) -> bool:
        """The client's maps strip on object ``name`` where its stage is made and the frame has
        none; whether it was added. Caller holds the lock."""
        stage = self.stages.get(name)
        if not isinstance(stage, Stage) or "maps" in client.frame or client.maps is None:
            return False
        client.frame["maps"] = png_data_url(maps_strip(project_material(client.maps, stage.screen)))
        client.maps_object = name
        return True

    def add_stage(self, name: str, stage) -> None:
        """Object ``name``'s :class:`Stage` made (or the exception that stopped it): the
        network waiting for it goes on, and every client showing it gets its maps strip."""
        with self.lock:
            self.stages[name] = stage
            for client in self.clients.values():
                if client.view is not None and client.view.object.name == name and self._show_maps(client, name):
                    self._changed(client)
            self.lock.notify_all()

    def wait_stage(self, name: str, job: Job):
        """Object ``name``'s stage (or why it could not be made) once the path tracer made it;
        None if ``job`` went stale or the server stopped meanwhile."""
        with self.lock:
            while (stage := self.stages.get(name)) is None:
                if self.stopped or self.network_slots.closed or not self.current(job):
                    return None
                self.lock.wait(1.0)
            return stage

    def current(self, job: Job) -> bool:
        with self.lock:
            client = self.clients.get(job.client)
            return client is not None and client.generation == job.generation

    def _changed(self, client: Client) -> None:
        client.version += 1
        client.frame["generation"], client.frame["version"] = client.generation, client.version
        self.lock.notify_all()

    def publish(
        self, job: Job, part: str, doc: dict, hdr: np.ndarray | None = None, variance: np.ndarray | None = None
    ) -> bool:
        """Store a result if its generation is still the client's and the server has not
        stopped; False (dropped) otherwise. A picture's ``hdr`` is kept and tone-mapped here at
        the client's exposure of now (the job's may be older: an exposure change does not
        restart the job)."""
        with self.lock:
            client = self.clients.get(job.client)
            if self.stopped or client is None or client.generation != job.generation:
                return False
            client.frame[part] = doc  # of the frame's generation: parts are cleared when it moves on
            if part == "network":
                client.network_hdr = hdr
            elif part == "path":
                client.path_hdr, client.path_variance = hdr, variance
            self._show(client, part)
            self._changed(client)
            return True

    def _show(self, client: Client, only: str | None = None) -> None:
        """The client's pictures as PNGs at its view's exposure (``only``: that part and the
        difference); caller holds the lock."""
        exposure = client.view.exposure
        held = {"network": client.network_hdr, "path": client.path_hdr, "reference": client.reference_hdr}
        for part, hdr in held.items():
            if hdr is not None and part in client.frame and only in (None, part):
                client.frame[part] = {
                    **client.frame[part],
                    "png": png_data_url(hdr_to_srgb8(hdr, exposure)),
                    "exposure": exposure,
                }
        if client.network_hdr is not None and client.path_hdr is not None:
            spp = client.frame["path"]["spp"]
            diff = difference(client.network_hdr, client.path_hdr, client.path_variance, exposure)
            client.frame["diff"] = {**diff, "spp": spp, "exposure": exposure}

    def frame(self, client_id: str, since: int, wait_s: float) -> dict:
        """The client's frame once its version passes ``since`` (or after ``wait_s``); at once,
        with ``"known": false``, when the hub holds nothing of the client, or forgets it
        meanwhile (module docstring). Makes no client."""
        deadline = time.monotonic() + wait_s
        with self.lock:
            client = self.seen(client_id)
            while client is not None and client.version <= since and (left := deadline - time.monotonic()) > 0:
                self.lock.wait(left)
                client = self.clients.get(client_id)
            if client is None:
                return {"version": 0, "known": False}
            return {"version": client.version, **client.frame, "known": True}

    def stop(self) -> None:
        """Publish nothing from now on (the server stops). Takes no lock: a signal handler calls it."""
        self.stopped = True

    def close(self) -> None:
        self.stop()
        self.path_slots.close()
        self.network_slots.close()


def _same_scene(client: Client, view: View, key: tuple) -> bool:
    """Whether ``view`` changes only the exposure of the client's view (same material, its maps
    not changed by an upload since, same light): then nothing is rendered again. The same view
    posted again is a new generation, as any view: it renders afresh."""
    held = client.view
    return (
        held is not None
        and client.generation > 0
        and client.maps is not None
        and client.material_key == key
        and held.light == view.light
        and held.object == view.object
        and held.exposure != view.exposure
    )


@dataclass(frozen=True)
class Stage:
    """An object as the server shows it: built, framed by its camera, and its G-buffers at the
    path tracer's resolution (``screen``) and the network's (``network``, None without one)."""

    ball: object
    camera: object
    screen: object
    network: object | None


class PathTracer(threading.Thread):
    """The one thread that calls Mitsuba: loads the G-buffers, then renders passes of jobs."""

    def __init__(self, hub: Hub, variant: str = "llvm", on_fatal=None):
        super().__init__(name="shaderball-path-tracer", daemon=True)
        self.hub, self.requested_variant = hub, variant
        self.ready, self.failure = threading.Event(), None
        self.on_fatal = on_fatal or (lambda exc: None)
        self.network_gbuffer = None
        self.scene = MaterialScene()
        self.scene_light = self.scene_stage = None
        self.stages: dict[str, Stage] = {}

    def run(self) -> None:
        try:
            self.variant = resolve_variant(self.requested_variant)
            self.mi = load_mitsuba(self.variant)
            # Errors only: Mitsuba's warnings (a render wound down by Ctrl-C, a sampler's rounding)
            # would print on the terminal the server owns; a failed render reaches the page instead.
            self.mi.logger().set_log_level(self.mi.LogLevel.Error)
            default = self.stage_of(DEFAULT_CHOICE)
            self.ball, self.camera = default.ball, default.camera
            self.hub.screen_gbuffer, self.network_gbuffer = default.screen, default.network
            self.settings = RenderSettings(
                resolution=self.hub.path_resolution, spp=PASS_TOTALS[-1], variant=self.variant
            )
        except BaseException as exc:  # noqa: BLE001 - handed to the thread that waits for ready
            self.failure = exc
            self.ready.set()
            return
        self.ready.set()
        while (job := self.hub.path_slots.take()) is not None:
            if not self.hub.current(job) or self.hub.park_if_abandoned(job):
                continue  # stale (a newer view replaced it), or its tab is gone (parked)
            try:
                self.render_pass(job)
            except KeyboardInterrupt as exc:  # Mitsuba's SIGINT handler cancelled a render
                self.on_fatal(exc)
                return
            except USER_ERRORS as exc:
                self.hub.publish(job, "error", {"message": str(exc)})
            except Exception as exc:  # noqa: BLE001 - shown in the page; the server goes on
                self.hub.publish(job, "error", {"message": f"path tracing failed: {type(exc).__name__}: {exc}"})

    def stage_of(self, choice) -> Stage:
        """The stage of ``choice`` (a :class:`pipeline.serve.scenes.ObjectChoice`), made the
        first time (mesh files passed their gate at start) and handed to the hub."""
        stage = self.stages.get(choice.name)
        if stage is not None:
            return stage
        try:
            ball = build_object(choice.name)
            camera = object_camera(ball)
            screen = load_gbuffer(ball, camera, self.hub.path_resolution, self.variant)
            net_res = self.hub.network_resolution
            network = load_gbuffer(ball, camera, net_res, self.variant) if net_res is not None else None
        except Exception as exc:
            self.hub.add_stage(choice.name, exc)  # the network waiting for it shows why
            raise
        stage = self.stages[choice.name] = Stage(ball, camera, screen, network)
        self.hub.add_stage(choice.name, stage)
        return stage

    def loaded_scene(self, job: Job, stage: Stage):
        """The held scene moved to the job's maps, object and light. A change of material,
        object or kind of light loads the scene afresh (a sun-lit scene has no map to turn,
        a map-lit one no sun to move)."""
        light = job.view.light
        if (
            self.scene.maps is not job.maps
            or self.scene_stage is not stage
            or is_environment(light) != is_environment(self.scene_light)
        ):
            self.scene.release()
            self.scene_light = None
        if self.scene_light != light:
            self.scene.lit(self.mi, stage.ball, stage.camera, job.maps, light, self.settings)
            self.scene_light, self.scene_stage = light, stage
        return self.scene.scene

    def render_pass(self, job: Job) -> None:
        """One chunk of the job's current pass; the pass's picture once the chunk completes it."""
        if job.pass_started is None:
            job.pass_started = time.perf_counter()
        stage = self.stage_of(job.view.object)
        scene = self.loaded_scene(job, stage)
        total = PASS_TOTALS[job.index]
        spp = min(CHUNK_SPP, total - job.acc.spp)
        image = self.mi.render(scene, spp=spp, seed=pass_seed(0, job.chunk))
        if scene.integrator().should_stop():
            raise KeyboardInterrupt("a render was cancelled by SIGINT")
        job.chunk += 1
        job.acc.add(np.asarray(image, dtype=np.float64), spp)
        if job.acc.spp < total:
            self.hub.path_slots.put(job, replace=False)  # the pass goes on unless a newer view came
            return
        started, job.pass_started = job.pass_started, None
        out = job.acc.mean()
        hdr = np.ascontiguousarray(out[..., 0:3], dtype=np.float32)
        variance = unbiased_variance(out, job.acc.spp)
        noise = None if variance is None else relative_error(out, job.acc.spp, stage.screen.mask, variance)
        # No "png": the hub tone-maps ``hdr`` at the client's exposure of the moment it publishes.
        doc = {
            "spp": job.acc.spp,
            "final": job.index + 1 == len(PASS_TOTALS),
            "pass_s": round(time.perf_counter() - started, 4),
            "seconds": round(time.perf_counter() - job.started, 4),
            "noise_rel": None if noise is None else round(noise, 4),  # None: not measurable yet (1 spp)
            "resolution": int(hdr.shape[0]),
        }
        if self.hub.publish(job, "path", doc, hdr, variance) and job.index + 1 < len(PASS_TOTALS):
            job.index += 1
            self.hub.path_slots.put(job, replace=False)  # a newer view, if any, stays first


class NetworkRunner(threading.Thread):
    """The thread that runs the network (torch) on each client's latest view."""

    def __init__(self, hub: Hub, network, scope=None):
        """``scope``: what the network learned from (pipeline.serve.scope.TrainingScope): a
        view outside it gets its picture with ``outside``, the sentence that says so."""
        super().__init__(name="shaderball-network", daemon=True)
        self.hub, self.network, self.scope = hub, network, scope

    def run(self) -> None:
        while (job := self.hub.network_slots.take()) is not None:
            if not self.hub.current(job):
                continue
            try:
                started = time.perf_counter()
                stage = self.hub.wait_stage(job.view.object.name, job)
                if stage is None:
                    continue  # stale meanwhile
                if isinstance(stage, BaseException):
                    raise stage
                screen = project_material(job.maps, stage.network)
                hdr, network_s = self.network(screen, job.view.light)
                doc = {  # the hub adds the picture, tone-mapped at the client's exposure
                    "network_ms": round(network_s * 1000, 2),
                    "frame_ms": round((time.perf_counter() - started) * 1000, 2),
                    "latency_ms": round((time.perf_counter() - job.started) * 1000, 2),
                    "resolution": int(hdr.shape[0]),
                    "outside": self.scope.warning(job.view.object, job.view.light) if self.scope else None,
                }
                self.hub.publish(job, "network", doc, hdr)
            except Exception as exc:  # noqa: BLE001 - shown in the page; the server goes on
                self.hub.publish(job, "error", {"message": f"the network failed: {type(exc).__name__}: {exc}"})
