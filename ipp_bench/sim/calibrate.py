"""Calibration of the belief's sensor model against the deployment's camera pipeline.

``python -m ipp_bench.sim.calibrate --task ipp_bench/MuJoCoWeed15-v1 [--fields 12] [--write]``

For calibration fields whose seeds are disjoint from every evaluation seed (fields are drawn from
``SeedSequence((CALIBRATION_KEY, i))``; evaluation episodes draw theirs from ``env.reset(seed)``'s
generator), the drone is placed over the map, and at each altitude hovers ``hover_s`` in the
episode's wind under the estimated-state controller and reads the camera pipeline at every
resolution factor f (1: per cell; the sensor's binning factor: 2 x 2 block means, read from the
binned image); then it moves ``second_look_m`` and looks again. A read-out's error against the
ground truth (e = H z_camera - H truth) is split three ways:

* common: the part of a cell's error that looks from *different* altitudes share (plant margins and
  colours that the pipeline gets wrong whatever the altitude), E[e_h e_h'] over cells. It is white
  per-cell variance of the camera-visible field, so it joins the GP prior's nugget;
* altitude-specific persistent: what two looks at the same altitude and factor share beyond the
  common part, E[e1 e2] - common * sum(w^2);
* look-to-look: E[(e1 - e2)^2] / 2 (pixel noise, sampling phase, misregistration, gusts).

Measured, errors of two looks correlate at ~0.95: a Kalman filter that took the whole error as
independent noise R would expect repeated looks to disagree far more than they do (NIS << 1), and
one that took only the look-to-look part would be surprised by every change of altitude (NIS >> 1).
R is fitted to look-to-look + altitude-specific by least squares on the logarithm with

    sigma^2(h, f) = f^e a (1 - exp(-b h))

(a [field units^2], b [1/m], e [-]: the sensor model of benchmark v1 with the binning exponent free;
e is kept in SensorConfig's range [0, 6]). ``--write`` puts a, b, e (e only when ``SensorConfig``
has ``binning_noise_exponent``) and the nugget (field family's nugget, refitted as ``ipp-bench
fit-prior`` does, plus the common part) into the task file with a comment naming the command.
The measured and fitted values are printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

CALIBRATION_KEY = 0x1BB_CA1  # first word of every calibration field's SeedSequence
E_RANGE = (0.0, 6.0)  # valid SensorConfig.binning_noise_exponent


@dataclass(frozen=True)
class CalibrationResult:
    altitudes: tuple[float, ...]  # [m]
    factors: tuple[int, ...]  # [-] resolution factors
    mse: np.ndarray  # (n_alt, n_f) mean squared error [field units^2]
    bias: np.ndarray  # (n_alt, n_f) mean error [field units]
    persistent: np.ndarray  # (n_alt, n_f) E[e1 e2] of two looks at the same altitude [field units^2]
    look_to_look: np.ndarray  # (n_alt, n_f) E[(e1 - e2)^2] / 2 [field units^2]
    rest: np.ndarray  # (n_alt, n_f) look-to-look + altitude-specific persistent variance: R's data [field units^2]
    count: np.ndarray  # (n_alt, n_f) number of scalar read-out pairs
    a: float
    b: float
    e: float
    camera_nugget: float  # [field units^2] per-cell error shared by looks at different altitudes
    e_free: float  # [-] the exponent fitted without SensorConfig's range

    def model(self, h, f) -> np.ndarray:
        return np.asarray(f, float) ** self.e * self.a * (1.0 - np.exp(-self.b * np.asarray(h, float)))


def fit_noise_model(altitudes, factors, mse, count=None, e_range=(-4.0, 8.0)) -> tuple[float, float, float]:
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
        e0 = min(max(1.0, e_range[0]), e_range[1])
        r = least_squares(residual, x0=[y0, lb0, e0],
                          bounds=([-30.0, math.log(1e-4), e_range[0]], [5.0, math.log(10.0), e_range[1] + 1e-12]))
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
            image_size: int | None = None, verbose: bool = True, second_look_m: float = 1.5) -> CalibrationResult:
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
    pairs = {(h, f): [] for h in altitudes for f in factors}
    width, height = cfg.grid.size_m
    t0 = time.perf_counter()

    def look(f, flat):
        """Rows (cells, weights, error) of the read-out at f, and the reading (per-cell fractions)."""
        reading = world.camera(binning=int(f))
        obs = sensors[f].observe(reading.estimated_xyz)
        obs = restrict(obs, reading.seen) if obs is not None else None
        if obs is None:
            return [], reading
        errors = obs.weights @ reading.fraction[obs.cells] - obs.weights @ flat[obs.cells]
        return [(obs.cells[w > 0], w[w > 0], float(e)) for w, e in zip(obs.weights, errors)], reading

    def again(rows, reading, flat):
        """(e1, e2, sum w^2): the same rows read from the second look's per-cell fractions."""
        return [(e1, float(w @ reading.fraction[c] - w @ flat[c]), float(w @ w)) for c, w, e1 in rows
                if reading.seen[c].all()]

    cross: list[float] = []  # products of per-cell errors of looks at different (altitude, factor)
    try:
        for i, (truth, seed) in enumerate(calibration_fields(cfg.grid, cfg.mission.field, n_fields)):
            world.begin_episode(truth, seed)
            rng = np.random.default_rng(seed)
            flat = truth.reshape(-1)
            for _ in range(positions_per_field):
                x, y = rng.uniform(0.15, 0.85) * width, rng.uniform(0.15, 0.85) * height
                cell_errors = {}
                for h in altitudes:
                    xyz = np.array([x, y, h])
                    world.flight.reset(xyz)
                    world.flight.hover(hover_s, at=xyz)
                    first = {}
                    for f in factors:
                        first[f], reading = look(f, flat)
                        err = np.where(reading.seen, reading.fraction - flat, np.nan)
                        cell_errors[(h, f)] = err
                    step = rng.normal(size=2)
                    step *= second_look_m / np.linalg.norm(step)
                    world.flight.hover(hover_s, at=xyz + np.array([step[0], step[1], 0.0]))
                    for f in factors:
                        pairs[(h, f)] += again(first[f], look(f, flat)[1], flat)
                keys = list(cell_errors)
                for ka in range(len(keys)):
                    for kb in range(ka + 1, len(keys)):
                        if keys[ka][0] == keys[kb][0]:
                            continue  # same altitude: not independent looks of the common part
                        prod = cell_errors[keys[ka]] * cell_errors[keys[kb]]
                        cross += prod[np.isfinite(prod)].tolist()
            if verbose:
                print(f"  field {i + 1}/{n_fields} done ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    finally:
        world.close()
    # the part of a cell's error that every look shares, whatever its altitude: white per-cell
    # variance of the camera-visible field (the nugget); the rest of each read-out's error is R
    camera_nugget = max(float(np.mean(cross)), 0.0) if cross else 0.0
    shape = (len(altitudes), len(factors))
    mse, bias, pers, ltl, rest = (np.full(shape, np.nan) for _ in range(5))
    count = np.zeros(shape, dtype=np.int64)
    for i, h in enumerate(altitudes):
        for j, f in enumerate(factors):
            e = np.array(pairs[(h, f)], dtype=np.float64).reshape(-1, 3)
            count[i, j] = len(e)
            if len(e):
                mse[i, j] = float(np.mean(e[:, 0] ** 2))
                bias[i, j] = float(np.mean(e[:, 0]))
                pers[i, j] = float(np.mean(e[:, 0] * e[:, 1]))
                ltl[i, j] = float(0.5 * np.mean((e[:, 0] - e[:, 1]) ** 2))
                # look-to-look error plus the persistent error this altitude and factor do not share
                # with the others (the common part is the nugget's: camera_nugget * sum w^2 per row)
                specific = max(float(np.mean(e[:, 0] * e[:, 1] - camera_nugget * e[:, 2])), 0.0)
                rest[i, j] = max(ltl[i, j] + specific, 1e-7)
    a, b, e = fit_noise_model(altitudes, factors, rest, count, E_RANGE)
    e_free = fit_noise_model(altitudes, factors, rest, count)[2]
    return CalibrationResult(tuple(float(h) for h in altitudes), tuple(int(f) for f in factors), mse, bias, pers,
                             ltl, rest, count, a, b, e, camera_nugget, e_free)


def _set_keys(text: str, section: str, values: list[tuple[str, str, str]], command: str) -> str:
    """``text`` with ``key = value  # comment`` lines set in ``[section]`` (added if missing), after a comment line."""
    header = f"[{section}]"
    lines = text.split("\n")
    if header not in lines:
        at = lines.index("[config.mission]") if "[config.mission]" in lines else len(lines)
        lines[at:at] = [header, ""]
    start = lines.index(header) + 1
    end = start
    while end < len(lines) and not lines[end].startswith("["):
        end += 1
    keys = {k for k, _, _ in values}
    mark = f"# fitted by `{command}`"
    body = [ln for ln in lines[start:end] if ln.split("=")[0].strip() not in keys
            and not ln.startswith("# fitted by `python -m ipp_bench.sim.calibrate")]
    while body and not body[-1].strip():
        body.pop()
    body += [mark] + [f"{k} = {v}  # {c}" for k, v, c in values] + [""]
    lines[start:end] = body
    return "\n".join(lines)


def write_task_file(path: str, a: float, b: float, e: float | None, command: str,
                    nugget: float | None = None) -> None:
    """Sets the fitted sensor constants (and the nugget) of a task file, with a comment naming the command."""
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    sensor = [("noise_a", f"{a:.6g}",
               "[field units^2] camera error not shared across altitudes: f^e a (1 - exp(-b h))"),
              ("noise_b", f"{b:.6g}", "[1/m]")]
    if e is not None:
        sensor.append(("binning_noise_exponent", f"{round(e, 3) + 0.0:g}",
                       "[-] variance factor f^e of a binned read-out"))
    text = _set_keys(text, "config.sensor", sensor, command)
    if nugget is not None:
        text = _set_keys(text, "config.gp", [("nugget", f"{nugget:.6g}", "[field units^2] field family's nugget "
                                               "+ the camera's persistent per-cell error variance")], command)
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
    p.add_argument("--field-nugget", type=float, default=None,
                   help="the field family's own nugget, added to the camera's (default: refit as `ipp-bench "
                        "fit-prior` does, so that the two commands compose in either order)")
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
    print(f"{'h [m]':>6} {'f':>2} | {'rows':>6} {'bias':>8} {'mse':>9} {'persist':>9} {'look2look':>9} "
          f"{'R data':>9} {'R fit':>9}")
    for i, h in enumerate(res.altitudes):
        for j, f in enumerate(res.factors):
            print(f"{h:6.1f} {f:2d} | {res.count[i, j]:6d} {res.bias[i, j]:+8.4f} {res.mse[i, j]:9.5f} "
                  f"{res.persistent[i, j]:9.5f} {res.look_to_look[i, j]:9.5f} {res.rest[i, j]:9.5f} "
                  f"{float(res.model(h, f)):9.5f}")
    print(f"per-cell error common to every altitude (joins the nugget): {res.camera_nugget:.5g}")
    print(f"R = look-to-look + altitude-specific persistent, fitted: "
          f"sigma^2(h, f) = f^{res.e:.3f} * {res.a:.5g} * (1 - exp(-{res.b:.4g} h)) "
          f"(e in SensorConfig's range {E_RANGE}; without that range e = {res.e_free:.3f})")
    if args.write:
        from ipp_bench.config import SensorConfig
        from ipp_bench.envs.registry import task_spec

        from ipp_bench.config import GPConfig

        has_e = any(fl.name == "binning_noise_exponent" for fl in dataclasses.fields(SensorConfig))
        has_nugget = any(fl.name == "nugget" for fl in dataclasses.fields(GPConfig))
        command = ("python -m ipp_bench.sim.calibrate " + " ".join(argv if argv is not None else sys.argv[1:])).strip()
        spec = task_spec(args.task)
        path = spec.source
        nugget = None
        if has_nugget:
            field_nugget = args.field_nugget
            if field_nugget is None:
                from ipp_bench import gp_fit

                field_nugget = gp_fit.fit_prior(spec.config, gp_fit.DEFAULT_MAPS, gp_fit.FIT_SEED).nugget
            nugget = field_nugget + res.camera_nugget
            print(f"nugget = {field_nugget:.4g} (field family) + {res.camera_nugget:.4g} (camera, persistent)")
        write_task_file(path, res.a, res.b, res.e if has_e else None, command, nugget)
        print(f"wrote {path}" + ("" if has_e else "; binning exponent not written (no SensorConfig."
                                                    "binning_noise_exponent here)")
              + ("" if has_nugget else "; nugget not written (no GPConfig.nugget here)"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
