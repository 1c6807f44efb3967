"""MuJoCo deployment: the weed-field scene, the quadrotor and its controller, the camera.

Modules (imports flow downwards):

- ``gl``: picks ``MUJOCO_GL`` (EGL, then OSMesa) before MuJoCo is imported; the only
  ``import mujoco`` of the package.
- ``texture``: per-seed ground texture of a weed field (numpy).
- ``quadrotor``, ``scene``: the airframe (an MJCF model, replaceable) and the scene, composed with
  dm_control's PyMJCF into a ``dm_control.mujoco.Physics``.
- ``controller``, ``flight``: reference legs (v1: velocity-continuous), cascaded position ->
  attitude -> thrust control, fixed-step physics; ``disturbance``: wind and state estimation.
- ``render``: the off-screen renderer (owns the GL context, created lazily, closed explicitly).
- ``camera``: image formation (blur, binning, exposure, white balance, pixel noise; per-episode
  conditions); ``vision``: the OpenCV pipeline from frame to per-cell weed fractions (v1);
  ``vision_v0``: the v0 per-pixel numpy pipeline.
- ``world``: all of the above for one grid; ``mission``: the MuJoCo platforms of a mission (their
  clock is the affordability oracle) and :class:`MuJoCoMission`; ``env``: the tasks
  ``ipp_bench/MuJoCoWeed15-v0`` / ``-v1``, their gymnasium env;
  ``dmenv``: :func:`load`, the dm_control environment (``control.Environment`` over a
  ``control.Task`` that holds the gymnasium env, and the world's ``dm_control.mujoco.Physics``); ``viewer``: the
  ``dm_control.viewer`` loader; ``calibrate``: the camera's noise model; ``video``: the demo video
  of an episode (``ipp-bench demo`` itself, which drives planners, is :mod:`ipp_bench.eval.demo`).

Needs ``pip install "ipp-bench[sim]"`` and a system EGL or OSMesa (see ``gl``). Every module
takes mujoco from ``ipp_bench.sim.gl``, so the backend is chosen whichever module is imported
first; this package file imports nothing at import time (``load`` imports when called), so
that ``ipp_bench.eval.demo`` (the CLI's argument parser, which imports ``ipp_bench.sim.video``)
loads without MuJoCo installed.
"""


def load(task_id: str = "ipp_bench/MuJoCoWeed15-v1", **overrides):
    """The deployment task ``task_id`` as a dm_control environment (:func:`ipp_bench.sim.dmenv.load`)."""
    from ipp_bench.sim.dmenv import load as _load

    return _load(task_id, **overrides)
