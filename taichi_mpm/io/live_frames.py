"""Frames drawn while the solver steps, on a worker thread of their own (output.render: clim and framing).

When the colour range and the camera are fixed before the run (render_options.known_in_advance), a frame needs
nothing from later outputs: each output's frame data (render.frame_data, numpy copies) goes through a bounded
queue to one worker thread, which made its own VTK window (VTK draws only in the thread that made it), renders the
frame, writes frames/frame_NNNNNN.png atomically and appends the picture to movie.mp4 as it goes (imageio's
ffmpeg writer into a temporary file, renamed over movie.mp4 when the run completes). The queue is that of
io.Writer: whoever hands a frame over waits only when it is full, a failed frame is raised at the next hand-over,
and `drain` finishes every frame already queued (the runner drains before it reports a stop).

A movie is fed here only when the run starts at its first output (a resumed run's movie is joined from the PNGs at
its end, render.make_movie); a run that stops or fails leaves no movie and no temporary behind.
"""
from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from . import files as io
from .writer import Writer

DEPTH = 3   # frames queued at most (each ~0.5 MB of copies for the main demo)


class LiveFrames:
    """A run's frames, rendered as they come. Same arguments as render.FrameRecorder, plus `movie`: the mp4 to feed
    (None: none) and `threaded` (False: each frame is drawn at once in the caller's thread)."""

    def __init__(self, frames_dir, render_cfg, dim: int, lower, upper, title: str | None = None, lines=None,
                 movie=None, fps: int = 20, threaded: bool = True):
        from .render import CAMERAS, check_size, framing_bounds, options

        o = options(render_cfg)
        if dim == 3 and o["camera"] not in CAMERAS:
            raise ValueError(f"unknown camera '{o['camera']}' (choose from {', '.join(CAMERAS)})")
        check_size(o["size"])
        self.dir = Path(frames_dir)
        self.root = self.dir.parent   # the run folder: no link inside it is followed
        self.render_cfg, self.dim, self.lower, self.upper = render_cfg, int(dim), lower, upper
        self.title, self.lines, self.color_by = title, lines, o["color_by"]
        self.limits = o["clim"]       # None for a label field: one colour per value, the same in every frame
        self.bounds = framing_bounds(render_cfg, dim, lower, upper)
        self.movie_path, self.fps = (Path(movie) if movie else None), fps
        self.spacing = None           # the first frame's, kept for the sequence (as the end-of-run path does)
        self.frames: list[Path] = []
        self.in_movie = 0             # frames appended to the movie
        self._renderer = None         # (the worker's) render.FrameRenderer, made by the first frame
        self._movie = None            # (the worker's) imageio writer
        self._movie_stack = None      # its temporary file (io.atomic_path), renamed when the run completes
        self.worker = Writer(threaded=threaded, depth=DEPTH, name="taichi-mpm-frames")

    @property
    def seconds(self) -> dict:
        return self.worker.seconds

    # ------------------------------------------------------------ the caller's side
    def record(self, particles: dict, time: float, index: int):
        """Hand one output's frame over (ValueError, here, for an unknown or absent colour field)."""
        from .render import frame_data

        d = frame_data(particles, self.color_by, self.dim)
        if self.spacing is None:
            self.spacing = d["spacing"]
        self.worker.submit("frames", self._draw, d, float(time), int(index))

    def drain(self):
        """Every frame handed over is written (and in the movie) when this returns."""
        self.worker.drain()

    def close(self, complete: bool):
        """Finish the queued frames and end the worker; complete: the run reached its end, so the movie (if it
        holds every frame from the first) is renamed into place; otherwise it is removed."""
        try:
            try:
                self.worker.submit("movie", self._end, bool(complete))
            finally:
                self.worker.close()
        finally:
            self._abandon()

    def _abandon(self):
        """After a failed frame the worker runs nothing more: the movie's temporary is removed here."""
        self._renderer = None   # (VTK's window belongs to the ended thread: left to the collector)
        movie, stack, self._movie, self._movie_stack = self._movie, self._movie_stack, None, None
        if movie is not None:
            with contextlib.suppress(Exception):
                movie.close()
            stack.__exit__(RuntimeError, RuntimeError("abandoned"), None)
            self.in_movie = 0

    @property
    def movie_done(self) -> bool:
        """The movie was written here (the runner joins it from the PNGs otherwise)."""
        return self.movie_path is not None and self.movie_path.is_file() and self.in_movie == len(self.frames) > 0

    # ------------------------------------------------------------ the worker
    def _draw(self, d: dict, time: float, index: int):
        from .render import FrameRenderer, write_png

        if self._renderer is None:
            self._renderer = FrameRenderer(self.render_cfg, self.dim, self.lower, self.upper, limits=self.limits,
                                           bounds=self.bounds, title=self.title, lines=self.lines)
            if self.movie_path is not None and index == 0:
                self._open_movie()
        img = self._renderer.image(d["x"], d["values"], time, spacing=self.spacing,
                                   volume=d["volume"] if len(d["volume"]) else None)
        io.ensure_folder(self.dir, root=self.root)
        out = self.dir / f"frame_{index:06d}.png"
        write_png(out, img, root=self.root)
        self.frames.append(out)
        if self._movie is not None:
            self._append(img)

    def _open_movie(self):
        import imageio.v2 as imageio

        stack = contextlib.ExitStack()
        tmp = stack.enter_context(io.atomic_path(self.movie_path, suffix=".mp4", root=self.root))
        self._movie = imageio.get_writer(tmp, fps=self.fps, codec="libx264", quality=7, macro_block_size=1,
                                         pixelformat="yuv420p", ffmpeg_log_level="error")
        self._movie_stack = stack

    def _append(self, img):
        h, w = img.shape[:2]
        if h % 2 or w % 2:  # yuv420p needs even sides (as render.make_movie)
            img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        self._movie.append_data(img)
        self.in_movie += 1

    def _end(self, complete: bool):
        """(the worker) Close the window; the movie renamed into place, or its temporary removed."""
        try:
            if self._renderer is not None:
                self._renderer.close()
                self._renderer = None
        finally:
            movie, stack, self._movie, self._movie_stack = self._movie, self._movie_stack, None, None
            if movie is not None:
                try:
                    movie.close()
                except BaseException as e:
                    stack.__exit__(type(e), e, e.__traceback__)
                    raise
                if complete and self.in_movie == len(self.frames):
                    stack.close()
                else:   # a stopped or failed run: no movie, no temporary
                    stack.__exit__(RuntimeError, RuntimeError("stopped"), None)
                    self.in_movie = 0
