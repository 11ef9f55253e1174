"""Progress on stderr, one printer per kind of command: a build's bar, validate's stages, a
study's steps, training's batches, evaluate's samples, a render's passes, and plain messages.

Hand-written rather than tqdm or rich: on a terminal a bar is redrawn in place (``\\r``);
anywhere else (a log, a batch job, a pipe) every update is a line of its own, in full, and a
build prints only when its count or what it waits on changes. tqdm (in the environment, through
a dependency) writes ``\\r`` redraws into a pipe or a log file as well; rich is not a
dependency. The tests and logs read these lines (docs/architecture.md).
"""

from __future__ import annotations

import sys
import time

import click


def format_seconds(seconds: float | None) -> str:
    """``"1:05"``, ``"1:00:05"``; ``"--:--"`` when unknown."""
    if seconds is None:
        return "--:--"
    seconds = int(seconds)
    return (
        f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"
        if seconds >= 3600
        else f"{seconds // 60}:{seconds % 60:02d}"
    )


def say(message: str) -> None:
    """A progress message, one line on stderr."""
    click.echo(message, err=True)


def build_progress():
    """A one-line progress bar on stderr: count, percentage, renders/s, elapsed, ETA, and what the
    build waits on (workers, batch jobs pending and why), printed again when either changes."""
    interactive = sys.stderr.isatty()
    last = {"done": -1, "message": "", "width": 0}

    def show(p):
        message = getattr(p, "message", "")
        if p.done == last["done"] and message == last["message"]:
            return
        last["done"], last["message"] = p.done, message
        width = 30
        filled = int(width * p.done / p.total) if p.total else width
        line = (
            f"[{'#' * filled}{'.' * (width - filled)}] {p.done}/{p.total} renders "
            f"{100.0 * p.done / max(p.total, 1):5.1f}%  {p.rate:.2f}/s  "
            f"elapsed {format_seconds(p.elapsed_s)}  ETA {format_seconds(p.eta_s)}"
            + (f"  | {message}" if message else "")
        )
        padded, last["width"] = line.ljust(last["width"]), len(line)
        click.echo(("\r" + padded) if interactive else line, err=True, nl=not interactive)
        if interactive and p.done >= p.total:
            click.echo("", err=True)

    return show


def validate_progress():
    """validate's (and --repair's) stages on stderr, at most one line a second until the last."""
    last = {"t": 0.0}

    def show(p):
        now = time.monotonic()
        if p.done < p.total and now - last["t"] < 1.0:
            return
        last["t"] = now
        read = f"files, {p.bytes_read / 1e6:.1f} MB read" if p.stage == "check" else "renders done"
        click.echo(f"{p.stage}: {p.done}/{p.total} {read}, {format_seconds(p.elapsed_s)}", err=True)

    return show


def study_progress(p: dict) -> None:
    """One line on stderr per step of a study (a note: its plan, a network's epochs)."""
    if "note" in p:
        click.echo(p["note"], err=True)
        return
    eta = f"  ETA {format_seconds(p['eta_s'])}" if p.get("eta_s") is not None else ""
    click.echo(f"[{p['done']}/{p['total']}] {p['what']}  elapsed {format_seconds(p['elapsed_s'])}{eta}", err=True)


def training_progress():
    """One line on stderr per batch: epoch, batch, loss, samples/s, ETA."""
    interactive = sys.stderr.isatty()
    bar = {"open": False}  # a bar line without its newline yet (interactive)

    def show(p):
        if "warning" in p:  # a run that does not learn says so (pipeline.neural.train)
            click.echo(("\n" if interactive else "") + f"warning: {p['warning']}", err=True)
            return
        if "note" in p:  # which loss the run trains with, and why; how long it will take
            click.echo(("\n" if bar["open"] else "") + p["note"], err=True)
            bar["open"] = False
            return
        width = 20
        filled = int(width * p["batch"] / p["batches"])
        line = (
            f"epoch {p['epoch']}/{p['epochs']} [{'#' * filled}{'.' * (width - filled)}] "
            f"batch {p['batch']}/{p['batches']}  loss {p['loss']:.4f}  {p['samples_per_s']:.1f} samples/s  "
            f"ETA {format_seconds(p['eta_s'])}"
        )
        click.echo(("\r" + line) if interactive else line, err=True, nl=not interactive)
        bar["open"] = interactive and p["batch"] != p["batches"]
        if interactive and p["batch"] == p["batches"]:
            click.echo("", err=True)

    return show


def evaluate_progress():
    """evaluate's bar on stderr, as a build's: samples done, percentage, samples/s, elapsed, ETA,
    and what runs now (the network, the equal-time measurement, path tracing at N spp)."""
    interactive = sys.stderr.isatty()
    last = {"width": 0}

    def show(p: dict):
        width = 30
        filled = int(width * p["done"] / p["total"]) if p["total"] else width
        line = (
            f"[{'#' * filled}{'.' * (width - filled)}] {p['done']}/{p['total']} samples "
            f"{100.0 * p['done'] / max(p['total'], 1):5.1f}%  {p['rate']:.2f}/s  "
            f"elapsed {format_seconds(p['elapsed_s'])}  ETA {format_seconds(p['eta_s'])}  | {p['what']}"
        )
        padded, last["width"] = line.ljust(last["width"]), len(line)
        click.echo(("\r" + padded) if interactive else line, err=True, nl=not interactive)
        if interactive and p["done"] >= p["total"]:
            click.echo("", err=True)

    return show


def render_progress():
    """render's bar on stderr: passes done of total, spp, elapsed, ETA and what runs now. On a
    terminal it is redrawn in place (every second while a pass renders); anywhere else a line
    is printed when the pass or the step changes, and every 10 s of a long pass."""
    interactive = sys.stderr.isatty()
    last = {"key": None, "t": 0.0, "width": 0}

    def show(p: dict):
        key, now = (p["done"], p["what"]), time.monotonic()
        if not interactive and key == last["key"] and now - last["t"] < 10.0:
            return
        last["key"], last["t"] = key, now
        width = 20
        filled = width * p["done"] // max(p["total"], 1)
        line = (
            f"[{'#' * filled}{'.' * (width - filled)}] pass {p['done']}/{p['total']} "
            f"({p['spp_done']}/{p['spp']} spp)  elapsed {format_seconds(p['elapsed_s'])}  "
            f"ETA {format_seconds(p['eta_s'])}  | {p['what']}"
        )
        padded, last["width"] = line.ljust(last["width"]), len(line)
        done = p["done"] >= p["total"]
        click.echo(("\r" + padded) if interactive else line, err=True, nl=not interactive or done)

    return show
