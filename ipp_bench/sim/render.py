"""Off-screen rendering of a :class:`WeedScene`: the one module that owns a GL context.

The context is created lazily, on the first :meth:`SceneRenderer.render`, in the
process that renders (never at import, never in a parent that forks workers),
and released by :meth:`SceneRenderer.close` (also a context manager). One
context serves every camera and image size up to ``SceneConfig.max_render_size``:
each call renders into a viewport of the requested size. When the scene's
ground texture changes (:meth:`WeedScene.set_ground`), the texture is uploaded
again before the next frame.
"""

from __future__ import annotations

import atexit
import math
import os
import weakref

import numpy as np

from ipp_bench.sim import gl as _gl
from ipp_bench.sim.gl import mujoco
from ipp_bench.sim.scene import WeedScene


def chase_camera(scene: WeedScene, distance: float = 7.0, azimuth: float = 45.0,
                 elevation: float = -38.0, drone: int = 0) -> mujoco.MjvCamera:
    """A camera that follows drone ``drone`` from above and behind (angles in degrees; azimuth 45 looks along +x +y)."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = scene.drones_ids[drone].body_id
    cam.distance, cam.azimuth, cam.elevation = distance, azimuth, elevation
    return cam


def azimuth_to_centre(scene: WeedScene, drone: int = 0) -> float:
    """Azimuth [deg] from drone ``drone`` towards the centre of the map (the chase view keeps the field in sight)."""
    adr = scene.drones_ids[drone].qpos_adr
    x, y = scene.data.qpos[adr: adr + 2]
    cx, cy = scene.cols * scene.resolution / 2.0, scene.rows * scene.resolution / 2.0
    if math.hypot(cx - x, cy - y) < 1e-6:
        return 45.0
    return math.degrees(math.atan2(cy - y, cx - x))


def follow_azimuth(current: float, target: float, rate: float) -> float:
    """Turns ``current`` towards ``target`` [deg] by the fraction ``rate`` of the shortest way."""
    delta = (target - current + 180.0) % 360.0 - 180.0
    return current + rate * delta


#: renderers with a GL context: closed at interpreter exit by :func:`_close_open_renderers`
_OPEN: weakref.WeakSet = weakref.WeakSet()

#: the process that made this interpreter's first GL context (None: none made yet). A process forked
#: from it (``fork``, gymnasium's default ``AsyncVectorEnv`` start method on Linux before Python 3.14)
#: inherits the GL driver's state but not its threads (Mesa's llvmpipe rasterisers, its shader-cache
#: queue): the first frame it renders waits for them for ever. It refuses to render instead.
_GL_OWNER_PID: int | None = None

FORKED_AFTER_RENDERING = (
    "this process was forked from one that had already rendered with OpenGL (MUJOCO_GL={backend}): the GL "
    "driver's threads do not survive fork, so rendering here would hang. Start the workers with 'forkserver' "
    "or 'spawn', e.g. gym.make_vec(task, n, vectorization_mode='async', vector_kwargs={{'context': "
    "'forkserver'}}), or make the vector env before the first frame is rendered")


def check_gl_usable() -> None:
    """Raise RuntimeError (:data:`FORKED_AFTER_RENDERING`) in a process forked from one that rendered."""
    if _GL_OWNER_PID is not None and _GL_OWNER_PID != os.getpid():
        raise RuntimeError(FORKED_AFTER_RENDERING.format(backend=os.environ.get("MUJOCO_GL", "<unset>")))


@atexit.register
def _close_open_renderers() -> None:
    """Free the GL contexts of renderers nobody closed (an env dropped without ``close()``).

    MuJoCo's EGL backend terminates its display in an ``atexit`` handler registered when the first
    context is made; a context freed after that (by the garbage collector at shutdown) prints an
    ``EGLError`` traceback. ``atexit`` runs the last registered first, so
    :meth:`SceneRenderer._open` registers this handler again after every context it makes.
    """
    for renderer in list(_OPEN):
        try:
            renderer.close()
        except Exception:  # noqa: BLE001 - at exit: nothing to report to
            pass


class SceneRenderer:
    """Renders RGB frames of a scene from its downward camera or any :class:`mujoco.MjvCamera`.

    Args:
        scene: the scene to draw (its current ``data``).
        max_geom: capacity of the abstract scene.
    """

    def __init__(self, scene: WeedScene, max_geom: int = 200) -> None:
        self.scene = scene
        self._max_geom = max_geom
        self._gl = None
        self._con = None
        self._scn = None
        self._opt = None
        self._pert = None
        self._texture_version = -1
        self._pid: int | None = None  # the process that made the context
        self._down = mujoco.MjvCamera()
        self._down.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._down.fixedcamid = scene.camera_id

    def down_camera(self, drone: int) -> mujoco.MjvCamera:
        """The downward camera of drone ``drone`` of a team scene (``render(None)`` is the first drone's)."""
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        cam.fixedcamid = self.scene.drones_ids[drone].camera_id
        return cam

    @property
    def is_open(self) -> bool:
        return self._con is not None

    def _open(self) -> None:
        global _GL_OWNER_PID
        check_gl_usable()
        model = self.scene.model
        width, height = model.vis.global_.offwidth, model.vis.global_.offheight
        try:
            gl_context = mujoco.GLContext(width, height)
            gl_context.make_current()
        except Exception as err:  # any backend failure: explain which library / apt package
            raise _gl.require_gl(err) from err
        if _GL_OWNER_PID is None:
            _GL_OWNER_PID = os.getpid()
        self._gl = gl_context
        self._pid = os.getpid()
        _OPEN.add(self)  # closed before EGL's own atexit terminates the display (see _close_open_renderers)
        atexit.unregister(_close_open_renderers)
        atexit.register(_close_open_renderers)  # after EGL's (made with the first context): runs before it
        self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100.value)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self._scn = mujoco.MjvScene(model, maxgeom=self._max_geom)
        self._opt = mujoco.MjvOption()
        self._pert = mujoco.MjvPerturb()
        self._texture_version = self.scene.texture_version  # MjrContext uploaded the current texture

    def render(self, camera: mujoco.MjvCamera | None = None, width: int = 128, height: int = 128,
               out: np.ndarray | None = None) -> np.ndarray:
        """Renders one RGB frame.

        Args:
            camera: None for the drone's downward camera, else e.g. :func:`chase_camera`.
            width, height: image size [px], at most ``SceneConfig.max_render_size``.
            out: optional (height, width, 3) uint8 array to fill.

        Returns:
            (height, width, 3) uint8, row 0 at the top of the image.
        """
        model = self.scene.model
        if not (0 < width <= model.vis.global_.offwidth and 0 < height <= model.vis.global_.offheight):
            raise ValueError(f"image size {width}x{height} outside 1..{model.vis.global_.offwidth}"
                             f"x{model.vis.global_.offheight} (SceneConfig.max_render_size)")
        if self._con is None:
            self._open()
        self._gl.make_current()
        if self._texture_version != self.scene.texture_version:
            mujoco.mjr_uploadTexture(model, self._con, self.scene.texture_id)
            self._texture_version = self.scene.texture_version
        cam = self._down if camera is None else camera
        mujoco.mjv_updateScene(model, self.scene.data, self._opt, self._pert, cam,
                               mujoco.mjtCatBit.mjCAT_ALL.value, self._scn)
        rect = mujoco.MjrRect(0, 0, width, height)
        mujoco.mjr_render(rect, self._scn, self._con)
        buf = np.empty((height, width, 3), dtype=np.uint8)
        mujoco.mjr_readPixels(buf, None, rect, self._con)
        if out is None:
            return buf[::-1].copy()
        out[...] = buf[::-1]
        return out

    def close(self) -> None:
        """Frees the GL resources (idempotent)."""
        if self._con is not None and self._pid != os.getpid():  # a forked copy: its GL calls would hang
            self._con = self._scn = self._gl = None
            return
        if self._con is not None:
            try:
                self._gl.make_current()
                self._con.free()
            finally:
                self._con = None
                self._scn = None
                self._gl.free()
                self._gl = None

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: GL may already be gone
            pass
