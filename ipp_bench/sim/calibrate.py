"""Calibration of the belief's camera model against the deployment's camera pipeline.

``python -m ipp_bench.sim.calibrate --task ipp_bench/MuJoCoWeed15-v1 [--fields 12] [--missions 4] [--write]``

Two measurements, both on calibration episodes disjoint from every evaluation episode.

1. Hovers (what the camera gets wrong, printed): for calibration fields drawn from
   ``SeedSequence((CALIBRATION_KEY, i))``, the drone hovers ``hover_s`` in the episode's wind at
   each altitude and reads the pipeline at every resolution factor f (1: per cell; the sensor's
   binning factor: 2 x 2 block means, read from the binned image), then moves ``second_look_m`` and
   looks again. Per altitude and factor: bias and MSE of a read-out's error e = H z - H truth, the
   part two looks share (E[e1 e2], persistent) and the look-to-look part (E[(e1 - e2)^2] / 2); and
   the per-cell error shared by looks from different altitudes. The look-to-look part fixes the
   altitude rate b of the white noise.

2. Calibration missions (the error model, written): full missions of random, coverage and greedy
   (``CALIBRATION_PLANNERS``: re-reads at one altitude, sweeps, altitude changes over read cells)
   on episodes ``CALIBRATION_EPISODES`` (seeds >= 2^31; the tasks' evaluation seeds are below). The
   camera's error is mostly persistent (two looks at a cell correlate at 0.8-0.9, at either
   factor), larger where a cell is part weed (plant margins) and near 0 on bare soil. The belief
   carries it as states (:class:`~ipp_bench.core.belief.PersistentErrorBelief`): a per-cell error per
   factor, correlated between the factors, with variance s_f phi(t), plus white noise
   f^e a (1 - exp(-b h)) phi(t), phi(t) = k + (1 - k) 4 t (1 - t). k is the ratio of the mean
   squared error of read-outs of about 0 to that of read-outs of about 0.5 (:func:`noise_floor`);
   a, e, s_1, s_binned and the correlation are fitted by maximum likelihood of the Kalman
   innovations of the calibration missions, replayed through the belief's own update
   (:func:`fit_error_model`). The NIS per degree of freedom of each planner's calibration missions
   under the fit is printed.

``--write`` puts a, b, e, the persistent constants, k and the nugget (the field family's own, refit
as ``ipp-bench fit-prior`` does: the camera's error is no longer part of the field) into the task
file with a comment naming the command. The greedy calibration missions plan with the constants
the task file holds when the command runs; what they read does not depend on them.

One module on purpose (over 400 lines): the two measurements and the fit that writes them into the
task file are one procedure with one command line.
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
E_RANGE = (-6.0, 6.0)  # valid SensorConfig.binning_noise_exponent
#: episode seeds [lo, hi) of the calibration missions: disjoint from every task's evaluation seeds [0, 2^31)
CALIBRATION_EPISODES = (2**31, 2**32)
#: planners whose missions the error model is fitted on: re-reads at one altitude (random), sweeps
#: at 8 m (coverage), and changes of altitude over read cells (greedy)
CALIBRATION_PLANNERS = ("random", "coverage", "greedy")
#: the constants the maximum-likelihood fit sets, in the order of its parameter vector
ERROR_MODEL_KEYS = ("noise_a", "binning_noise_exponent", "persistent_var", "persistent_var_binned",
                    "persistent_corr", "noise_floor")


@dataclass(frozen=True)
class CalibrationResult:
    altitudes: tuple[float, ...]  # [m]
    factors: tuple[int, ...]  # [-] resolution factors
    mse: np.ndarray  # (n_alt, n_f) mean squared error [field units^2]
    bias: np.ndarray  # (n_alt, n_f) mean error [field units]
    persistent: np.ndarray  # (n_alt, n_f) E[e1 e2] of two looks at the same altitude [field units^2]
    look_to_look: np.ndarray  # (n_alt, n_f) E[(e1 - e2)^2] / 2 [field units^2]
    rest: np.ndarray  # (n_alt, n_f) look-to-look + altitude-specific persistent variance [field units^2]
    count: np.ndarray  # (n_alt, n_f) number of scalar read-out pairs
    # f^e a (1 - exp(-b h)) fitted to ``rest``: the white R of v1 before the error states, kept to compare
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
    from ipp_bench.core.fields import make_field

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
    from ipp_bench.core.sensor import Sensor
    from ipp_bench.envs.registry import task_spec
    from ipp_bench.sim.world import SimConfig, WeedWorld, restrict

    spec = task_spec(task_id)
    cfg = spec.config
    sim = SimConfig.from_dict(spec.sim) if spec.sim else SimConfig()
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


def fly_calibration_missions(task_id: str, n_fields: int, planners=CALIBRATION_PLANNERS,
                             verbose: bool = True, budget_s: float | None = None,
                             ) -> list[tuple[list[tuple[list, list, float]], np.ndarray]]:
    """Full missions of ``planners`` on ``n_fields`` calibration episodes: each mission's Kalman
    batches ``(read-outs, values, time)`` as fused (:attr:`MuJoCoMission.update_log`) and its truth."""
    from ipp_bench.envs import make_env
    from ipp_bench.planners.episode import fly_episode

    budget = {} if budget_s is None else {"budget_s": float(budget_s)}
    env = make_env(task_id, episode_seeds=CALIBRATION_EPISODES, **budget)
    out = []
    t0 = time.perf_counter()
    try:
        for planner in planners:
            for i in range(n_fields):
                fly_episode(env, planner, i)
                out.append((list(env.mission.update_log), env.mission.truth.reshape(-1).copy()))
            if verbose:
                print(f"  {planner}: {n_fields} calibration missions flown ({time.perf_counter() - t0:.1f} s)",
                      file=sys.stderr)
    finally:
        env.close()
    return out


def error_model_constants(x) -> dict[str, float]:
    """The fit's parameter vector (logs and logits) as SensorConfig constants."""
    la, e, ls1, ls2, lr, lk = (float(v) for v in x)
    return {"noise_a": math.exp(la), "binning_noise_exponent": e, "persistent_var": math.exp(ls1),
            "persistent_var_binned": math.exp(ls2), "persistent_corr": 1.0 / (1.0 + math.exp(-lr)),
            "noise_floor": 1.0 / (1.0 + math.exp(-lk))}


def _with_constants(observations, sensor) -> list:
    """``observations`` with var / persistent of ``sensor`` (a SensorConfig), whatever they were flown with."""
    out = []
    for o in observations:
        white = sensor.noise_a * (1.0 - math.exp(-sensor.noise_b * o.altitude))
        if o.factor > 1:
            white *= float(o.factor) ** sensor.binning_noise_exponent
        # the belief reads only var - persistent (the white part): persistent is s_f sum(w^2) here, not the
        # sensor's s_f w^T C w, which needs the grid positions of the cells (it cancels either way)
        persistent = sensor.persistent(o.factor) * np.einsum("ij,ij->i", o.weights, o.weights)
        out.append(dataclasses.replace(o, var=white + persistent, persistent=persistent))
    return out


def replay(missions, config, sensor) -> list[tuple[float, float, int]]:
    """Per mission: (negative log-likelihood, NIS, dof) of its Kalman batches under ``sensor``'s error model."""
    from ipp_bench.core.belief import GPBelief, PersistentErrorBelief

    prior = GPBelief.prior(config.grid, config.gp)
    out = []
    for batches, _ in missions:
        model = PersistentErrorBelief(prior.copy(), sensor)
        nll, nis, dof = 0.0, 0.0, 0
        for observations, zs, _ in batches:
            observations = _with_constants(observations, sensor)
            nu, S = model.innovation(observations, zs)
            L = np.linalg.cholesky(S)
            a = np.linalg.solve(L, nu)
            q = float(a @ a)
            nll += 0.5 * q + float(np.log(np.diag(L)).sum())
            nis, dof = nis + q, dof + nu.size
            model.update(observations, zs)
        out.append((nll, nis, dof))
    return out


def noise_floor(missions, empty: float = 0.02, half: tuple[float, float] = (0.4, 0.6)) -> float:
    """k of :func:`~ipp_bench.core.belief.value_scale` by moments: the mean squared error of read-outs
    whose value is <= ``empty`` over that of read-outs valued in ``half`` (errors against the truth)."""
    sq, t = [], []
    for batches, truth in missions:
        for observations, zs, _ in batches:
            for o, z in zip(observations, zs):
                sq.append((z - o.weights @ truth[o.cells]) ** 2)
                t.append(z)
    sq, t = np.concatenate(sq), np.concatenate(t)
    low, mid = sq[t <= empty], sq[(t >= half[0]) & (t <= half[1])]
    if low.size == 0 or mid.size == 0:
        return 1.0
    return float(min(max(low.mean() / mid.mean(), 1e-3), 1.0))


def fit_error_model(missions, config, noise_b: float, floor: float, max_evaluations: int = 300,
                    verbose: bool = True) -> tuple[dict[str, float], float]:
    """Maximum-likelihood fit of the camera's error model to calibration missions.

    Fits ``ERROR_MODEL_KEYS`` but the noise floor (white noise scale a and binning exponent e,
    persistent variances at both factors and their correlation) by Nelder-Mead on the innovations'
    Gaussian log-likelihood, sum over batches of (nu^T S^-1 nu + log det S) / 2, with the altitude
    rate b (from the hovers) and the floor k (:func:`noise_floor`) fixed: read-outs of bare soil
    are exactly 0 again and again, and a free k would run to 0 to make their likelihood unbounded.
    Returns (constants, negative log-likelihood).
    """
    from scipy.optimize import minimize

    base = config.sensor
    lk = math.log(floor / (1.0 - floor)) if floor < 1.0 else 30.0

    def nll(x):
        sensor = dataclasses.replace(base, noise_b=noise_b, **error_model_constants([*x, lk]))
        try:
            return sum(r[0] for r in replay(missions, config, sensor))
        except np.linalg.LinAlgError:  # S not positive definite in floating point: not a model to pick
            return math.inf

    x0 = np.array([math.log(1e-3), -1.0, math.log(3e-3), math.log(1e-2), math.log(0.9 / 0.1)])
    t0 = time.perf_counter()
    res = minimize(nll, x0, method="Nelder-Mead", options={"maxfev": max_evaluations, "xatol": 0.02, "fatol": 0.5})
    if verbose:
        print(f"  error model: {res.nfev} likelihood evaluations ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    const = error_model_constants([*res.x, lk])
    const["noise_floor"] = float(floor)
    const["binning_noise_exponent"] = min(max(const["binning_noise_exponent"], E_RANGE[0]), E_RANGE[1])
    return const, float(res.fun)


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


SENSOR_COMMENTS = {
    "noise_a": "[field units^2] look-to-look (white) noise: f^e a (1 - exp(-b h)) at t = 0.5",
    "noise_b": "[1/m]",
    "binning_noise_exponent": "[-] variance factor f^e of a binned read-out's white noise",
    "persistent_var": "[field units^2] per-cell error every full-resolution look repeats, at t = 0.5",
    "persistent_var_binned": "[field units^2] per-cell error every binned look repeats, at t = 0.5",
    "persistent_corr": "[-] correlation of a cell's persistent errors at the two factors",
    "noise_floor": "[-] error variance of an empty or full cell relative to a half-covered one",
}


def write_task_file(path: str, sensor: dict[str, float], command: str, nugget: float | None = None) -> None:
    """Sets the fitted sensor constants (and the nugget) of a task file, with a comment naming the command."""
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    values = [(k, f"{round(v, 3) + 0.0:g}" if k == "binning_noise_exponent" else f"{v:.6g}", SENSOR_COMMENTS[k])
              for k, v in sensor.items()]
    text = _set_keys(text, "config.sensor", values, command)
    if nugget is not None:
        comment = "[field units^2] the field family's own nugget (the camera's errors: the sensor's states)"
        text = _set_keys(text, "config.gp", [("nugget", f"{nugget:.6g}", comment)], command)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ipp_bench.sim.calibrate", description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="ipp_bench/MuJoCoWeed15-v1",
                   help="MuJoCo deployment task (id or task file) whose camera model is calibrated "
                        "(default ipp_bench/MuJoCoWeed15-v1)")
    p.add_argument("--fields", type=int, default=12, help="calibration fields of the hovers (default 12)")
    p.add_argument("--positions", type=int, default=6, help="hover positions per field and altitude (default 6)")
    p.add_argument("--altitudes", default="6,8,10,12,14,16",
                   help="hover altitudes [m], comma-separated (default 6,8,10,12,14,16)")
    p.add_argument("--factors", default="1,2", help="resolution factors, comma-separated (default 1,2)")
    p.add_argument("--hover-s", type=float, default=1.0, help="hover before each read-out [s] (default 1)")
    p.add_argument("--missions", type=int, default=4,
                   help=f"calibration missions per planner ({', '.join(CALIBRATION_PLANNERS)}) for the error "
                        "model's likelihood (default 4)")
    p.add_argument("--evaluations", type=int, default=300, help="likelihood evaluations at most (default 300)")
    p.add_argument("--field-nugget", type=float, default=None,
                   help="the field family's own nugget (default: refit as `ipp-bench fit-prior` does, so that the "
                        "two commands compose in either order)")
    p.add_argument("--neighbour-corr", type=float, default=None,
                   help="fit the error model with this correlation of neighbouring cells' persistent errors "
                        "(default: the task's persistent_neighbour_corr; it is measured, never fitted, and not "
                        "written)")
    p.add_argument("--write", action="store_true",
                   help="write the fitted constants into the task file (default: print them only)")
    args = p.parse_args(argv)
    if args.fields < 1 or args.positions < 1 or args.missions < 1 or args.evaluations < 1:
        p.error("--fields, --positions, --missions and --evaluations must be >= 1")
    altitudes = [float(v) for v in args.altitudes.split(",")]
    factors = [int(v) for v in args.factors.split(",")]
    if any(h <= 0 for h in altitudes) or any(f < 1 for f in factors):
        p.error("--altitudes must be > 0 m and --factors >= 1")
    if args.neighbour_corr is not None and not 0.0 <= args.neighbour_corr < 1.0:
        p.error(f"--neighbour-corr {args.neighbour_corr} is invalid: expected a number in [0, 1)")
    from ipp_bench.envs.registry import task_spec

    spec = task_spec(args.task)
    res = measure(args.task, altitudes, factors, args.fields, args.positions, args.hover_s)
    print(f"task {args.task}: {args.fields} calibration fields x {args.positions} positions, hover {args.hover_s} s")
    print(f"{'h [m]':>6} {'f':>2} | {'rows':>6} {'bias':>8} {'mse':>9} {'persist':>9} {'look2look':>9}")
    for i, h in enumerate(res.altitudes):
        for j, f in enumerate(res.factors):
            print(f"{h:6.1f} {f:2d} | {res.count[i, j]:6d} {res.bias[i, j]:+8.4f} {res.mse[i, j]:9.5f} "
                  f"{res.persistent[i, j]:9.5f} {res.look_to_look[i, j]:9.5f}")
    print(f"per-cell error shared by looks from different altitudes: {res.camera_nugget:.5g}")
    _, b, _ = fit_noise_model(res.altitudes, res.factors, res.look_to_look, res.count)
    print(f"altitude rate of the look-to-look noise: b = {b:.4g} 1/m")
    # the error model: maximum likelihood over calibration missions, with the prior's field nugget
    if args.field_nugget is None:
        from ipp_bench.core import gp_fit

        field_nugget = gp_fit.fit_prior(spec.config, gp_fit.DEFAULT_MAPS, gp_fit.FIT_SEED).nugget
    else:
        field_nugget = args.field_nugget
    config = dataclasses.replace(spec.config, gp=dataclasses.replace(spec.config.gp, nugget=field_nugget))
    if args.neighbour_corr is not None:
        config = dataclasses.replace(config, sensor=dataclasses.replace(
            config.sensor, persistent_neighbour_corr=args.neighbour_corr))
    missions = fly_calibration_missions(args.task, args.missions)
    floor = noise_floor(missions)
    const, nll = fit_error_model(missions, config, b, floor, args.evaluations)
    const = {"noise_a": const.pop("noise_a"), "noise_b": b, **const}
    print("error model (maximum likelihood over the calibration missions, -log L = "
          f"{nll:.1f}): " + ", ".join(f"{k} = {v:.5g}" for k, v in const.items()))
    sensor = dataclasses.replace(config.sensor, **const)
    per = replay(missions, config, sensor)
    for i, planner in enumerate(CALIBRATION_PLANNERS):
        part = per[i * args.missions:(i + 1) * args.missions]
        print(f"  NIS per dof on its calibration missions, {planner}: "
              f"{sum(r[1] for r in part) / sum(r[2] for r in part):.3f}")
    if args.write:
        command = ("python -m ipp_bench.sim.calibrate " + " ".join(argv if argv is not None else sys.argv[1:])).strip()
        write_task_file(spec.source, const, command, field_nugget)
        print(f"wrote {spec.source} (nugget = {field_nugget:.4g}, the field family's own)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
