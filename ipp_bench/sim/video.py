"""The demo video of a MuJoCo episode: frame composition and H.264 encoding (no planner here).

Each video frame shows a chase view of the drone; the last measured frame as the camera delivered
it (image formation, binning) and its weed mask with the per-cell fractions the pipeline read,
written at the cells' centres; the ground truth, the belief mean and standard deviation with the
grid, the camera footprint of the last read-out (from the estimated pose) and the path coloured by
mission time (with its colour bar); trace(P) over the ground-truth ROI against mission time; and,
in the title bar, mission time, altitude, wind and the state estimate's error against the truth.
Frames are taken every ``speedup / fps`` seconds of simulated time, so a 200 s mission at the
defaults (10 fps, 4x) gives a 50 s video. A team's video (:class:`~ipp_bench.sim.team.MuJoCoTeamEnv`)
shows a chase view of every drone, every drone's last frame with its weed mask, and on the maps every
drone's path, position and camera footprint (one colour per drone) over the shared belief.
Which planner flies, and the comparison plot, are ``ipp-bench demo``'s business
(:mod:`ipp_bench.eval.demo`), above the planners.

The same arguments give the same video, frame for frame and byte for byte: physics, rendering,
sensor noise and planners are seeded, and the encoder runs with a fixed thread count.

One module on purpose (over 400 lines): the frame's panels and the encoder that writes them share
the frame's layout and the abort on a signal.
"""

from __future__ import annotations

import math

import numpy as np


# -- episodes ------------------------------------------------------------------------------------
def make_sim_env(task: str, budget: float | None = None):
    """The unwrapped environment of ``task``; it must be a MuJoCo task (entry point in ``ipp_bench.sim``)."""
    import ipp_bench.envs as envs

    spec = envs.task_spec(task)
    if "deployment" not in spec.tags:  # the MuJoCo tasks carry the tag
        deploy = envs.tagged("deployment")
        raise ValueError(f"task {spec.id!r} is not simulated in MuJoCo: the demo needs one of {deploy}")
    overrides = {} if budget is None else {"budget_s": float(budget)}
    return envs.make_env(spec.id, **overrides)


# -- video ---------------------------------------------------------------------------------------
#: a team's drones on the maps: dot, footprint (the first drone red, as a single drone's dot)
DRONE_COLOURS = ("red", "cyan", "yellow", "lime", "orange", "white", "deepskyblue", "violet")


class DemoVideo:
    """Composes and encodes the demo frames of one episode.

    Static parts (titles, axes, colour bars, ground truth) are drawn once by matplotlib; per frame,
    the camera images and belief maps are pasted into the canvas as pixels and only the path,
    trace curve and status line are drawn by matplotlib (blitting), ~30 ms a frame.

    Args:
        env: a :class:`~ipp_bench.sim.env.MuJoCoIPPEnv` after ``reset``.
        path: output mp4.
        title: planner / task line at the top.
        size: (width, height) [px].
        fps, speedup, crf, hold_s: see :func:`add_demo_arguments`.
        progress: optional tqdm bar over mission seconds.
    """

    FIG_WIDTH = 12.8  # [in]; dpi = width / 12.8, so fonts and layout scale with the video size

    def __init__(self, env, path: str, title: str, size=(1280, 720), fps: int = 10, speedup: float = 4.0,
                 crf: int = 32, hold_s: float = 1.0, progress=None):
        from matplotlib import colormaps
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.cm import ScalarMappable
        from matplotlib.collections import LineCollection
        from matplotlib.colors import Normalize
        from matplotlib.figure import Figure

        from ipp_bench.sim.render import azimuth_to_centre, chase_camera, follow_azimuth

        self.env, self.mission = env, env.mission
        self.world = env.world
        self.n = len(self.world.flights)  # drones: a team's video shows each of them
        self.size, self.fps, self.hold_s = size, int(fps), float(hold_s)
        self.interval = float(speedup) / float(fps)  # [s] of mission time between frames
        self.next_t = 0.0
        self.frames = 0
        self.progress = progress
        self._chase = chase_camera(self.world.scene)
        self._aim, self._follow = azimuth_to_centre, follow_azimuth
        cfg = env.config
        width_m, height_m = cfg.grid.size_m
        extent = (0.0, width_m, 0.0, height_m)
        budget = cfg.mission.budget_s
        std0 = math.sqrt(cfg.gp.signal_variance)
        self._maps = [(colormaps["viridis"], Normalize(0.0, 1.0)), (colormaps["magma"], Normalize(0.0, std0))]

        w, h = size
        figsize = (self.FIG_WIDTH, self.FIG_WIDTH * h / w)
        fig = Figure(figsize=figsize, dpi=w / self.FIG_WIDTH, facecolor="white")
        self.fig, self.canvas = fig, FigureCanvasAgg(fig)
        fig.text(0.01, 0.985, title, fontsize=12, weight="bold", va="top")
        self._status = fig.text(0.99, 0.985, "", fontsize=10, ha="right", va="top", animated=True)

        def axes(rect, name):
            ax = fig.add_axes(rect)
            ax.set_title(name, fontsize=10)
            ax.set_xticks([])
            ax.set_yticks([])
            return ax

        def map_axes(rect, name):
            ax = fig.add_axes(rect)
            ax.set_title(name, fontsize=10)
            ax.tick_params(labelsize=7)
            ax.set_xlim(0, width_m)
            ax.set_ylim(0, height_m)
            ax.set_aspect("equal")
            return ax

        square = 0.235 * figsize[0] / figsize[1]  # figure height fraction of a 0.235-wide square
        if self.n == 1:
            ax_chase = axes([0.01, 0.45, 0.48, 0.46], "chase view")
            ax_cam = axes([0.51, 0.91 - square, 0.235, square], "last measured frame (as read out)")
            ax_mask = axes([0.755, 0.91 - square, 0.235, square], "weed mask, per-cell fractions")
        else:
            chase_axes, cam_axes = self._team_axes(axes, figsize)
        ax_truth = map_axes([0.035, 0.06, 0.17, 0.30], "ground truth (weed fraction)")
        ax_truth.imshow(self.mission.truth, origin="lower", extent=extent, vmin=0, vmax=1, cmap="viridis")
        ax_mean = map_axes([0.245, 0.06, 0.17, 0.30], "belief mean")
        ax_std = map_axes([0.455, 0.06, 0.17, 0.30], "belief std, path by time")
        for ax, (cmap, norm) in zip((ax_mean, ax_std), self._maps):
            fig.colorbar(ScalarMappable(norm, cmap), ax=ax, fraction=0.046, pad=0.02).ax.tick_params(labelsize=7)
        res = cfg.grid.resolution
        for ax in (ax_truth, ax_mean, ax_std):  # the grid cells
            for x in np.arange(0.0, width_m + 1e-9, res):
                ax.axvline(x, color="white", lw=0.3, alpha=0.35)
            for y in np.arange(0.0, height_m + 1e-9, res):
                ax.axhline(y, color="white", lw=0.3, alpha=0.35)
        cax = fig.add_axes([0.955, 0.09, 0.008, 0.27])
        tbar = fig.colorbar(ScalarMappable(Normalize(0.0, budget), colormaps["plasma"]), cax=cax)
        tbar.ax.tick_params(labelsize=7)
        tbar.set_label("path colour: mission time [s]", fontsize=7, labelpad=2)
        # per drone: its footprint on the three maps, its path and position on the belief maps
        self._paths, self._drones, self._footprints = [], [], []
        for k in range(self.n):
            colour = "cyan" if self.n == 1 else DRONE_COLOURS[k % len(DRONE_COLOURS)]
            for ax in (ax_truth, ax_mean, ax_std):
                (fp,) = ax.plot([], [], "-", color=colour, lw=1.2, animated=True)
                self._footprints.append(fp)
        self._cell_texts = []
        for k in range(self.n):
            for ax in (ax_mean, ax_std):
                lc = LineCollection([], cmap="plasma", linewidths=2.0, animated=True)
                lc.set_clim(0, budget)
                ax.add_collection(lc)
                self._paths.append(lc)
                face = "red" if self.n == 1 else DRONE_COLOURS[k % len(DRONE_COLOURS)]
                (dot,) = ax.plot([], [], "o", ms=6, mfc=face, mec="white", animated=True)
                self._drones.append(dot)
        ax_tr = fig.add_axes([0.685, 0.09, 0.245, 0.27])
        ax_tr.set_title("trace(P) over the ROI", fontsize=10)
        ax_tr.set_xlabel("mission time [s]", fontsize=8)
        ax_tr.tick_params(labelsize=7)
        ax_tr.set_xlim(0, budget)
        prior = self.mission.history[0].trace_roi
        ax_tr.set_ylim(0, prior * 1.05 if prior > 0 else 1.0)
        ax_tr.grid(alpha=0.3)
        (self._trace,) = ax_tr.plot([], [], "-", color="tab:blue", lw=2, drawstyle="steps-post", animated=True)
        self._animated = [*self._paths, *self._drones, *self._footprints, self._trace, self._status]
        self.canvas.draw()
        if self.canvas.get_width_height() != (w, h):
            raise ValueError(f"--size {w}x{h}: the figure renders at {self.canvas.get_width_height()}; "
                             "use a size whose width is a multiple of 16 px per 12.8 in, e.g. 1280x720")
        self._background = self.canvas.copy_from_bbox(fig.bbox)
        # pixel boxes (row0, row1, col0, col1) of the pasted images, from the drawn axes
        self._box_mean, self._box_std = self._box(ax_mean), self._box(ax_std)
        if self.n == 1:
            self._box_chase, self._box_cam, self._box_mask = (self._box(ax) for ax in (ax_chase, ax_cam, ax_mask))
            side = min(self._box_cam[1] - self._box_cam[0], self._box_cam[3] - self._box_cam[2])
            self._box_cam = self._square(self._box_cam, side)
            self._box_mask = self._square(self._box_mask, side)
        else:
            self._chases = [chase_camera(self.world.scene, drone=k) for k in range(self.n)]
            self._boxes_chase = [self._box(ax) for ax in chase_axes]
            self._boxes_cam = []
            for ax in cam_axes:
                box = self._box(ax)
                self._boxes_cam.append(self._square(box, min(box[1] - box[0], box[3] - box[2])))
        shape = self.mission.truth.shape
        self._map_index = [self._upsample_index(b, shape) for b in (self._box_mean, self._box_std)]

        self._writer = H264Writer(path, (w, h), self.fps, crf)

    def _team_axes(self, axes, figsize) -> tuple[list, list]:
        """A team's panels: a chase view per drone side by side, and each drone's frame with its weed
        mask in a grid of squares beside them."""
        n, gap = self.n, 0.01
        width = (0.48 - gap * (n - 1)) / n
        chase = [axes([0.01 + k * (width + gap), 0.45, width, 0.46], f"UAV {k} chase view") for k in range(n)]
        per_row = n if n <= 2 else math.ceil(math.sqrt(n))
        rows = math.ceil(n / per_row)
        side_w = min((0.48 - gap * (per_row - 1)) / per_row, (0.46 / rows - 0.04) * figsize[1] / figsize[0])
        side_h = side_w * figsize[0] / figsize[1]
        cams = []
        for k in range(n):
            r, c = divmod(k, per_row)
            cams.append(axes([0.51 + c * (side_w + gap), 0.91 - side_h - r * (side_h + 0.04), side_w, side_h],
                             f"UAV {k} frame, weed mask"))
        return chase, cams

    def _box(self, ax) -> tuple[int, int, int, int]:
        """Inner pixel box of ``ax`` as (row0, row1, col0, col1), rows from the top."""
        bb = ax.get_window_extent()
        h = self.size[1]
        c0, c1 = int(math.ceil(bb.x0)) + 1, int(math.floor(bb.x1))
        r0, r1 = h - int(math.floor(bb.y1)) + 1, h - int(math.ceil(bb.y0))
        return r0, r1, c0, c1

    @staticmethod
    def _square(box, side):
        r0, r1, c0, c1 = box
        r0 += ((r1 - r0) - side) // 2
        c0 += ((c1 - c0) - side) // 2
        return r0, r0 + side, c0, c0 + side

    @staticmethod
    def _upsample_index(box, shape):
        r0, r1, c0, c1 = box
        rows, cols = shape
        ri = ((np.arange(r1 - r0) + 0.5) / (r1 - r0) * rows).astype(int)[::-1]  # origin lower
        ci = ((np.arange(c1 - c0) + 0.5) / (c1 - c0) * cols).astype(int)
        return np.ix_(ri, ci)

    # -- per step / per frame -------------------------------------------------------------------
    def hook(self, mission) -> None:
        """Step hook of the mission (a team's: of its drones): grabs every frame that is due."""
        del mission  # the simulated time is the world's
        t = self.world.flight.time_s
        while t >= self.next_t - 1e-9:
            self.grab(t)
            self.next_t += self.interval

    def grab(self, t: float) -> None:
        self._writer.send(self.compose(t))
        self.frames += 1
        if self.progress is not None:
            self.progress.update(min(t, self.progress.total) - self.progress.n)

    def compose(self, t: float) -> np.ndarray:
        """The (H, W, 3) uint8 frame at mission time ``t``."""
        if self.n > 1:
            return self._compose_team(t)
        mission, world = self.mission, self.world
        renderer = world.renderer
        self.canvas.restore_region(self._background)
        buf = np.asarray(self.canvas.buffer_rgba())
        r0, r1, c0, c1 = self._box_chase
        # the chase view turns smoothly (about 2 s time constant) to keep the map centre ahead
        rate = min(1.0, self.interval / 2.0) if self.frames else 1.0
        self._chase.azimuth = self._follow(self._chase.azimuth, self._aim(world.scene), rate)
        buf[r0:r1, c0:c1, :3] = renderer.render(self._chase, c1 - c0, r1 - r0)
        reading = world.last_reading
        r0, r1, c0, c1 = self._box_cam
        side = r1 - r0
        if reading is not None:
            frame, weed = reading.frame, reading.weed_mask.astype(bool)
        else:
            frame = renderer.render(None, side, side)
            weed = world.cfg.segmenter(frame).astype(bool)
        idx = (np.arange(side) * frame.shape[0] // side)
        buf[r0:r1, c0:c1, :3] = frame[np.ix_(idx, idx)]
        shaded = (frame * 0.35).astype(np.uint8)
        shaded[weed] = (255, 40, 200)
        r0, r1, c0, c1 = self._box_mask
        buf[r0:r1, c0:c1, :3] = shaded[np.ix_(idx, idx)]
        self._cell_labels(reading, (r0, r1, c0, c1))
        shape = mission.truth.shape
        values = (mission.belief.mean.reshape(shape), np.sqrt(np.maximum(mission.belief.variance, 0.0)).reshape(shape))
        for (cmap, norm), box, index, v in zip(self._maps, (self._box_mean, self._box_std), self._map_index, values):
            r0, r1, c0, c1 = box
            buf[r0:r1, c0:c1, :3] = cmap(norm(v), bytes=True)[..., :3][index]
        here = world.flight.position
        path = np.array([p for p in mission.path if p[0] <= t + 1e-9] + [(t, *here)])
        seg = np.stack([path[:-1, 1:3], path[1:, 1:3]], axis=1)
        for lc, dot in zip(self._paths, self._drones):
            lc.set_segments(seg)
            lc.set_array(path[1:, 0])
            dot.set_data([here[0]], [here[1]])
        hist = [(r.time_s, r.trace_roi) for r in mission.history if r.time_s <= t + 1e-9]
        hist.append((t, mission.history[-1].trace_roi))
        ht = np.array(hist)
        self._trace.set_data(ht[:, 0], ht[:, 1])
        fx, fy = [], []
        if reading is not None and reading.footprint is not None:
            fx = list(reading.footprint[:, 0]) + [reading.footprint[0, 0]]
            fy = list(reading.footprint[:, 1]) + [reading.footprint[0, 1]]
        for fp in self._footprints:
            fp.set_data(fx, fy)
        red = mission.history[-1].uncertainty_reduction_pct
        flight = world.flight
        wind = flight.wind
        err = float(np.linalg.norm(flight.estimated_position() - here))
        self._status.set_text(f"t {t:5.1f} s | {here[2]:4.1f} m | wind {np.hypot(wind[0], wind[1]):3.1f} m/s from "
                              f"{np.degrees(np.arctan2(-wind[1], -wind[0])) % 360:3.0f} deg | estimate - truth "
                              f"{err:4.2f} m | uncertainty red. {red:5.1f} %")
        for artist in [*self._animated, *self._cell_texts]:
            if artist.axes is not None:
                artist.axes.draw_artist(artist)
            else:
                self.fig.draw_artist(artist)
        return np.ascontiguousarray(buf[..., :3])

    def _compose_team(self, t: float) -> np.ndarray:
        """A team's frame at mission time ``t``: every drone's chase view, frame, path and footprint."""
        mission, world = self.mission, self.world
        renderer = world.renderer
        self.canvas.restore_region(self._background)
        buf = np.asarray(self.canvas.buffer_rgba())
        rate = min(1.0, self.interval / 2.0) if self.frames else 1.0
        for k, (cam, (r0, r1, c0, c1)) in enumerate(zip(self._chases, self._boxes_chase)):
            cam.azimuth = self._follow(cam.azimuth, self._aim(world.scene, drone=k), rate)
            buf[r0:r1, c0:c1, :3] = renderer.render(cam, c1 - c0, r1 - r0)
        for k, (r0, r1, c0, c1) in enumerate(self._boxes_cam):
            reading = world.last_readings[k]
            side = r1 - r0
            if reading is not None:
                frame, weed = reading.frame, reading.weed_mask.astype(bool)
            else:
                frame = renderer.render(renderer.down_camera(k) if k else None, side, side)
                weed = world.cfg.segmenter(frame).astype(bool)
            shaded = (frame * 0.35).astype(np.uint8)
            shaded[weed] = (255, 40, 200)
            idx = (np.arange(side) * frame.shape[0] // side)
            buf[r0:r1, c0:c1, :3] = shaded[np.ix_(idx, idx)]
        shape = mission.truth.shape
        values = (mission.belief.mean.reshape(shape), np.sqrt(np.maximum(mission.belief.variance, 0.0)).reshape(shape))
        for (cmap, norm), box, index, v in zip(self._maps, (self._box_mean, self._box_std), self._map_index, values):
            r0, r1, c0, c1 = box
            buf[r0:r1, c0:c1, :3] = cmap(norm(v), bytes=True)[..., :3][index]
        for k, flight in enumerate(world.flights):
            here = flight.position
            path = np.array([p for p in mission.paths[k] if p[0] <= t + 1e-9] + [(t, *here)])
            seg = np.stack([path[:-1, 1:3], path[1:, 1:3]], axis=1)
            for lc, dot in zip(self._paths[2 * k: 2 * k + 2], self._drones[2 * k: 2 * k + 2]):
                lc.set_segments(seg)
                lc.set_array(path[1:, 0])
                dot.set_data([here[0]], [here[1]])
            reading = world.last_readings[k]
            fx, fy = [], []
            if reading is not None and reading.footprint is not None:
                fx = list(reading.footprint[:, 0]) + [reading.footprint[0, 0]]
                fy = list(reading.footprint[:, 1]) + [reading.footprint[0, 1]]
            for fp in self._footprints[3 * k: 3 * k + 3]:
                fp.set_data(fx, fy)
        hist = [(r.time_s, r.trace_roi) for r in mission.history if r.time_s <= t + 1e-9]
        hist.append((t, mission.history[-1].trace_roi))
        ht = np.array(hist)
        self._trace.set_data(ht[:, 0], ht[:, 1])
        red = mission.history[-1].uncertainty_reduction_pct
        wind = world.flight.wind
        heights = " ".join(f"{f.position[2]:4.1f}" for f in world.flights)
        self._status.set_text(f"t {t:5.1f} s | {heights} m | wind {np.hypot(wind[0], wind[1]):3.1f} m/s from "
                              f"{np.degrees(np.arctan2(-wind[1], -wind[0])) % 360:3.0f} deg | {self.n} UAVs, one "
                              f"belief | uncertainty red. {red:5.1f} %")
        for artist in self._animated:
            if artist.axes is not None:
                artist.axes.draw_artist(artist)
            else:
                self.fig.draw_artist(artist)
        return np.ascontiguousarray(buf[..., :3])

    def _cell_labels(self, reading, box) -> None:
        """Per-cell weed fractions of the last read-out, written at the cells' centres in the mask panel."""
        for txt in self._cell_texts:
            txt.remove()
        self._cell_texts = []
        if reading is None or reading.cell_pixels is None:
            return
        r0, r1, c0, c1 = box
        h = self.size[1]
        fig_w, fig_h = self.size
        scale = (r1 - r0) / reading.frame.shape[0]
        for cell, (u, v) in reading.cell_pixels.items():
            px, py = c0 + u * scale, r0 + v * scale  # pixel in the video frame (rows from the top)
            if not (c0 <= px < c1 and r0 <= py < r1):
                continue
            self._cell_texts.append(self.fig.text(px / fig_w, (h - py) / fig_h, f"{reading.fraction[cell]:.2f}",
                                                  fontsize=6, color="white", ha="center", va="center",
                                                  animated=True))

    def abort(self) -> None:
        """Stops the encoder after a failure: the partial video is removed, a file that was at the
        output path before is left as it was."""
        self._writer.abort()

    def close(self, t_end: float) -> int:
        """Writes the hold frames, finishes the file (in place only now), returns the number of frames.

        Raises:
            OutputWriteError: the encoder could not write the video (a full disk, say); the old file,
                if any, is left as it was.
        """
        for _ in range(int(round(self.hold_s * self.fps))):
            self.grab(t_end)
        self._writer.close()
        return self.frames


class H264Writer:
    """Encodes rgb24 frames to an H.264 mp4 with ffmpeg (imageio-ffmpeg's binary), atomically.

    ffmpeg writes a temporary sibling of ``path`` (:func:`ipp_bench.core.data.temporary_sibling`); only
    :meth:`close`, after ffmpeg has finished without error, renames it into place. An interrupted or
    failed video (Ctrl-C, SIGTERM, a planner that raised, a full disk) never replaces the file that
    was there: :meth:`abort` stops ffmpeg and removes the temporary file (after SIGKILL it is left
    beside the old one, hidden, and the old one is intact). ffmpeg's exit status and its last error
    line are checked, so a full disk is an error, not a truncated video.
    """

    def __init__(self, path, size: tuple[int, int], fps: int, crf: int):
        import subprocess
        import tempfile
        from fractions import Fraction
        from pathlib import Path

        import imageio_ffmpeg

        from ipp_bench.core.data import temporary_sibling

        self.path = Path(path)
        self.tmp = temporary_sibling(self.path)
        self._log = tempfile.TemporaryFile()  # ffmpeg's messages (a pipe could fill and block it)
        w, h = size
        cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-f", "rawvideo", "-vcodec", "rawvideo", "-s", f"{w}x{h}",
               "-pix_fmt", "rgb24", "-r", str(Fraction(fps).limit_denominator()), "-i", "-", "-an",
               "-vcodec", "libx264", "-pix_fmt", "yuv420p", "-v", "warning",
               "-crf", str(int(crf)), "-preset", "medium", "-threads", "2", "-movflags", "+faststart",
               "-tune", "animation", str(self.tmp)]
        # its own session: Ctrl-C in a terminal reaches this process, which stops ffmpeg itself
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._log,
                                      start_new_session=True)

    def _failed(self, what: str):
        from ipp_bench.core.data import OutputWriteError

        try:  # it is ending: let it say why
            self._proc.wait(timeout=10.0)
        except Exception:
            pass
        self._stop()
        self._log.seek(0)
        lines = [ln.strip() for ln in self._log.read().decode(errors="replace").splitlines() if ln.strip()]
        self._remove_tmp()
        rc = self._proc.returncode
        if lines:
            cause = lines[-1]
        elif rc is not None and rc < 0:
            import signal

            cause = f"ffmpeg was killed by {signal.Signals(-rc).name}"  # e.g. SIGXFSZ: past the file size limit
        else:
            cause = what
        return OutputWriteError(f"cannot write {self.path}: {cause} (the video encoder ffmpeg stopped; "
                                f"{'the old file is left as it was' if self.path.exists() else 'nothing was written'})")

    def send(self, frame: np.ndarray) -> None:
        """Writes one (H, W, 3) uint8 frame."""
        try:
            self._proc.stdin.write(np.ascontiguousarray(frame, dtype=np.uint8).tobytes())
        except OSError:  # ffmpeg has gone (a full disk, say): its own message says why
            raise self._failed("it exited while frames were sent") from None

    def close(self) -> None:
        """Finishes the video and renames it into place; raises OutputWriteError if ffmpeg failed."""
        import os

        try:
            self._proc.stdin.close()
        except OSError:
            pass
        if self._proc.wait() != 0:
            raise self._failed(f"ffmpeg exited with status {self._proc.returncode}")
        try:
            with open(self.tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            os.replace(self.tmp, self.path)
        except OSError as err:
            self._remove_tmp()
            from ipp_bench.core.data import OutputWriteError

            raise OutputWriteError(f"cannot write {self.path}: {err.strerror or err}") from None
        finally:
            self._log.close()

    def abort(self) -> None:
        """Stops ffmpeg and removes the partial video (the file at ``path``, if any, is untouched)."""
        self._stop()
        self._remove_tmp()
        self._log.close()

    def _stop(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait()
        try:
            self._proc.stdin.close()
        except OSError:
            pass

    def _remove_tmp(self) -> None:
        try:
            self.tmp.unlink()
        except OSError:
            pass


def expected_frames(t_end: float, fps: int, speedup: float, hold_s: float) -> int:
    """Frames a demo of a mission ending at ``t_end`` [s] writes."""
    interval = speedup / fps
    return int(math.floor(t_end / interval + 1e-9)) + 1 + int(round(hold_s * fps))
