"""Calibration of the belief's sensor model against the deployment's camera pipeline.

``python -m ipp_bench.sim.calibrate --task ipp_bench/MuJoCoWeed15-v1 [--fields 12] [--write]``

For calibration fields whose seeds are disjoint from every evaluation seed (fields are drawn from
``SeedSequence((CALIBRATION_KEY, i))``; evaluation episodes draw theirs from ``env.reset(seed)``'s
generator), the drone is placed over the map at each altitude, hovers ``hover_s`` in the episode's
wind under the estimated-state controller, and the camera pipeline is read at every resolution
factor f (1: per cell; the sensor's binning factor: 2 x 2 block means, read from the binned
image). Each read-out's error against the ground truth (H z_camera - H truth) is collected per
(altitude, f). The mean squared error (bias included: the Kalman filter must cover it) is fitted by
least squares on its logarithm with

    sigma^2(h, f) = f^e a (1 - exp(-b h))

(a [field units^2], b [1/m], e [-]), the sensor model of benchmark v1 with the binning exponent
free. ``--write`` puts a, b (and e, when the installed ``SensorConfig`` has
``binning_noise_exponent``) into the task file's ``[config.sensor]`` with a comment naming the
command. The table of measured and fitted values is printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import sys
import time
from dataclasses import dataclass

import numpy as np

CALIBRATION_KEY = 0x1BB_CA1  # first word of every calibration field's SeedSequence


@dataclass(frozen=True)
class CalibrationResult:
    altitudes: tuple[float, ...]  # [m]
    factors: tuple[int, ...]  # [-] resolution factors
    mse: np.ndarray  # (n_alt, n_f) mean squared error [field units^2]
    bias: np.ndarray  # (n_alt, n_f) mean error [field units]
    count: np.ndarray  # (n_alt, n_f) number of scalar read-outs
    a: float
    b: float
    e: float

    def model(self, h, f) -> np.ndarray:
        return np.asarray(f, float) ** self.e * self.a * (1.0 - np.exp(-self.b * np.asarray(h, float)))


def fit_noise_model(altitudes, factors, mse, count=None) -> tuple[float, float, float]:
    """Least-squares fit of log mse(h, f) = e log f + log a + log(1 - exp(-b h)); returns (a, b, e).

    Weighted by the read-out counts (the log of a mean of n squares has variance ~2 / n).
    """
    from scipy.optimize import least_squares

    H, F = np.meshgrid(np.asarray(altitudes, float), np.asarray(factors, float), indexing="ij")
    y = np.log(np.asarray(mse, float))
    w = np.sqrt(np.asarray(count, float) / 2.0) if count is not None else np.ones_like(y)
    ok = np.isfinite(y) & (w > 0)
    single_f = len(set(np.asarray(factors).tolist())) == 1

    def residual(p):
        la, lb, e = p
        if single_f:
            e = 3.0
        model = e * np.log(F) + la + np.log(-np.expm1(-np.exp(lb) * H))
        return ((model - y) * w)[ok]

    y0 = float(np.mean(y[ok]))
    best = None
    for lb0 in (math.log(0.02), math.log(0.2), math.log(1.0)):
        r = least_squares(residual, x0=[y0, lb0, 1.0], bounds=([-30.0, math.log(1e-4), -4.0], [5.0, math.log(10.0), 8.0]))
        if best is None or r.cost < best.cost:
            best = r
    la, lb, e = best.x
    return float(math.exp(la)), float(math.exp(lb)), (3.0 if single_f else float(e))


def calibration_fields(grid, family: str, n: int) -> list[tuple[np.ndarray, int]]:
    """(truth, episode seed) of the ``n`` calibration fields (seeds disjoint from evaluation)."""
    from ipp_bench.fields import make_field

    out = []
    for i in range(n):
        ss = np.random.SeedSequence((CALIBRATION_KEY, i))
        field_ss, episode_ss = ss.spawn(2)
        truth = make_field(family, grid, np.random.default_rng(field_ss))
        out.append((truth, int(episode_ss.generate_state(1, np.uint64)[0])))
    return out


def measure(task_id: str, altitudes, factors, n_fields: int, positions_per_field: int, hover_s: float,
            image_size: int | None = None, verbose: bool = True) -> CalibrationResult:
    """Flies the calibration and fits the noise model (see the module docstring)."""
    import ipp_bench.envs  # noqa: F401  (registers the tasks)
    from ipp_bench.envs.registry import task_spec
    from ipp_bench.sensor import Sensor
    from ipp_bench.sim.env import MuJoCoIPPEnvV1
    from ipp_bench.sim.world import WeedWorld, restrict

    spec = task_spec(task_id)
    cfg = spec.config
    sim = MuJoCoIPPEnvV1.default_sim()
    if image_size is not None:
        sim = sim.with_image_size(image_size)
    world = WeedWorld(cfg.grid, cfg.sensor, cfg.mission.speed, sim)
    sensors = {}
    for f in factors:
        if f == 1:
            sc = dataclasses.replace(cfg.sensor, binning=1)
        else:
            sc = dataclasses.replace(cfg.sensor, binning=int(f), binning_altitude=1e-3)
        sensors[f] = Sensor(cfg.grid, sc)
    errors = {(h, f): [] for h in altitudes for f in factors}
    width, height = cfg.grid.size_m
    t0 = time.perf_counter()
    try:
        for i, (truth, seed) in enumerate(calibration_fields(cfg.grid, cfg.mission.field, n_fields)):
            world.begin_episode(truth, seed)
            rng = np.random.default_rng(seed)
            flat = truth.reshape(-1)
            for h in altitudes:
                for _ in range(positions_per_field):
                    xyz = np.array([rng.uniform(0.15, 0.85) * width, rng.uniform(0.15, 0.85) * height, h])
                    world.flight.reset(xyz)
                    world.flight.hover(hover_s, at=xyz)
                    for f in factors:
                        reading = world.camera(binning=int(f))
                        obs = sensors[f].observe(reading.estimated_xyz)
                        obs = restrict(obs, reading.seen) if obs is not None else None
                        if obs is None:
                            continue
                        e = obs.weights @ reading.fraction[obs.cells] - obs.weights @ flat[obs.cells]
                        errors[(h, f)].append(e)
            if verbose:
                print(f"  field {i + 1}/{n_fields} done ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    finally:
        world.close()
    shape = (len(altitudes), len(factors))
    mse, bias, count = np.zeros(shape), np.zeros(shape), np.zeros(shape, dtype=np.int64)
    for i, h in enumerate(altitudes):
        for j, f in enumerate(factors):
            e = np.concatenate(errors[(h, f)]) if errors[(h, f)] else np.zeros(0)
            count[i, j] = e.size
            mse[i, j] = float(np.mean(e * e)) if e.size else np.nan
            bias[i, j] = float(np.mean(e)) if e.size else np.nan
    a, b, e = fit_noise_model(altitudes, factors, mse, count)
    return CalibrationResult(tuple(float(h) for h in altitudes), tuple(int(f) for f in factors), mse, bias, count,
                             a, b, e)


def write_task_file(path: str, a: float, b: float, e: float | None, command: str) -> None:
    """Replaces (or adds) the ``[config.sensor]`` noise constants of a task file, naming the command."""
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    lines = [f"# fitted by `{command}`",
             f"noise_a = {a:.6g}  # [field units^2]",
             f"noise_b = {b:.6g}  # [1/m]"]
    if e is not None:
        lines.append(f"binning_noise_exponent = {e:.4g}  # [-] variance factor f^e of a binned read-out")
    block = "[config.sensor]\n" + "\n".join(lines) + "\n"
    pattern = re.compile(r"\[config\.sensor\]\n(?:(?!\[).*\n)*", re.MULTILINE)
    if pattern.search(text):
        keep = []
        for line in pattern.search(text).group(0).splitlines()[1:]:
            key = line.split("=")[0].strip()
            if key and not line.startswith("#") and key not in ("noise_a", "noise_b", "binning_noise_exponent"):
                keep.append(line)
        block = "[config.sensor]\n" + "\n".join(keep + lines) + "\n\n"
        text = pattern.sub(lambda _m: block, text, count=1)
    else:
        text = text.replace("[config.mission]", block + "\n[config.mission]", 1)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ipp_bench.sim.calibrate", description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="ipp_bench/MuJoCoWeed15-v1")
    p.add_argument("--fields", type=int, default=12, help="calibration fields (default 12)")
    p.add_argument("--positions", type=int, default=6, help="hover positions per field and altitude (default 6)")
    p.add_argument("--altitudes", default="6,8,10,12,14,16", help="altitudes [m], comma-separated")
    p.add_argument("--factors", default="1,2", help="resolution factors, comma-separated")
    p.add_argument("--hover-s", type=float, default=1.0, help="hover before each read-out [s] (default 1)")
    p.add_argument("--write", action="store_true", help="write the fitted constants into the task file")
    args = p.parse_args(argv)
    if args.fields < 1 or args.positions < 1:
        p.error("--fields and --positions must be >= 1")
    altitudes = [float(v) for v in args.altitudes.split(",")]
    factors = [int(v) for v in args.factors.split(",")]
    if any(h <= 0 for h in altitudes) or any(f < 1 for f in factors):
        p.error("--altitudes must be > 0 m and --factors >= 1")
    res = measure(args.task, altitudes, factors, args.fields, args.positions, args.hover_s)
    print(f"task {args.task}: {args.fields} calibration fields x {args.positions} positions, hover {args.hover_s} s")
    print(f"{'h [m]':>6} {'f':>2} | {'n':>6} {'bias':>8} {'mse':>9} {'fit':>9}")
    for i, h in enumerate(res.altitudes):
        for j, f in enumerate(res.factors):
            print(f"{h:6.1f} {f:2d} | {res.count[i, j]:6d} {res.bias[i, j]:+8.4f} {res.mse[i, j]:9.5f} "
                  f"{float(res.model(h, f)):9.5f}")
    print(f"fit: sigma^2(h, f) = f^{res.e:.3f} * {res.a:.5g} * (1 - exp(-{res.b:.4g} h))")
    if args.write:
        from ipp_bench.config import SensorConfig
        from ipp_bench.envs.registry import task_spec

        has_e = any(fl.name == "binning_noise_exponent" for fl in dataclasses.fields(SensorConfig))
        command = ("python -m ipp_bench.sim.calibrate " + " ".join(argv if argv is not None else sys.argv[1:])).strip()
        path = task_spec(args.task).source
        write_task_file(path, res.a, res.b, res.e if has_e else None, command)
        print(f"wrote {path}" + ("" if has_e else " (binning exponent not written: SensorConfig has no "
                                                    "binning_noise_exponent field here)"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
