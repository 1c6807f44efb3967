"""A deployment task is data: its TOML's [sim] table, overridable by name with one-line errors."""

import dataclasses

import gymnasium as gym
import pytest

pytest.importorskip("mujoco")

import ipp_bench.envs  # noqa: E402,F401
from ipp_bench.cli import main  # noqa: E402
from ipp_bench.envs.registry import task_spec  # noqa: E402
from ipp_bench.sim.env import MuJoCoIPPEnv  # noqa: E402
from ipp_bench.sim.world import SimConfig, sim_field_owners  # noqa: E402


def test_v0_and_v1_differ_in_data_not_in_classes():
    v0, v1 = task_spec("MuJoCoWeed15-v0"), task_spec("MuJoCoWeed15-v1")
    assert v0.entry_point == v1.entry_point == "ipp_bench.sim.env:MuJoCoIPPEnv"
    assert SimConfig.from_dict(v0.sim) == SimConfig.v0()
    assert SimConfig.from_dict(v1.sim) == SimConfig()
    e0 = gym.make("ipp_bench/MuJoCoWeed15-v0").unwrapped
    e1 = gym.make("ipp_bench/MuJoCoWeed15-v1").unwrapped
    assert type(e0) is type(e1) is MuJoCoIPPEnv
    assert e0.sim_config == SimConfig.v0() and e1.sim_config == SimConfig()
    assert e0.world.flight.cfg.mode == "stop" and e1.world.flight.cfg.mode == "continuous"
    e0.close(), e1.close()


def test_overrides_by_name_reach_the_simulation():
    env = gym.make("ipp_bench/MuJoCoWeed15-v1", wind_max=1.5, image_size=64, mode="stop", budget_s=30.0).unwrapped
    sim = env.sim_config
    assert sim.disturbances.wind_max == 1.5 and sim.camera.image_size == 64 and sim.flight.mode == "stop"
    assert env.world.cfg is sim and env.world.flight.cfg.mode == "stop"
    assert env.config.mission.budget_s == 30.0
    # everything else as in the task file
    assert dataclasses.replace(sim, disturbances=SimConfig().disturbances, camera=SimConfig().camera,
                               flight=SimConfig().flight) == SimConfig()
    env.close()


def test_every_sim_field_name_is_unique_and_not_a_config_field():
    from ipp_bench.core.config import field_owners

    assert not set(sim_field_owners()) & set(field_owners())


@pytest.mark.parametrize("item, message", [
    ("wind_max=-1", "DisturbanceConfig.wind_max must be a finite number >= 0, got -1.0"),
    ("image_size=20", "CameraModel.image_size must be an integer in [32, 1280] px, got 20"),
    ("mode=hover", "FlightConfig.mode must be one of ('continuous', 'stop'), got 'hover'"),
    ("sun_zenith_deg=3", "sun_zenith_deg = 3 is invalid: expected 2 numbers"),
    ("open_px=1.5", "open_px = 1.5 is invalid: expected an integer"),
    ("no_such_field=1", "or a [sim] field of ipp_bench/MuJoCoWeed15-v1"),
])
def test_bad_env_overrides_are_one_line(item, message, capsys):
    rc = main(["evaluate", "--task", "MuJoCoWeed15-v1", "--planner", "random", "--env", "budget_s=5", "--env", item])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and "Traceback" not in err and err.count("\n") == 1


def test_bad_sim_tables_are_refused_naming_the_key():
    with pytest.raises(ValueError, match=r"unknown \[sim.camera\] field 'pixels'"):
        SimConfig.from_dict({"camera": {"pixels": 3}})
    with pytest.raises(ValueError, match=r"unknown \[sim\] key 'wind'"):
        SimConfig.from_dict({"wind": 3})
    with pytest.raises(ValueError, match=r"\[sim.flight\] must be a table"):
        SimConfig.from_dict({"flight": "stop"})


def test_the_platform_is_the_tasks_flight_mode():
    from ipp_bench.sim.mission import ContinuousFlight, StopAndGoFlight

    for task, mode, cls in (("ipp_bench/MuJoCoWeed15-v1", None, ContinuousFlight),
                            ("ipp_bench/MuJoCoWeed15-v1", "stop", StopAndGoFlight),
                            ("ipp_bench/MuJoCoWeed15-v0", None, StopAndGoFlight)):
        env = gym.make(task, budget_s=12.0, **({"mode": mode} if mode else {})).unwrapped
        env.reset(seed=0)
        assert type(env.mission.platform) is cls
        # the core mission books what the platform flew: one leg, its clock, its read-outs, NIS per update
        mask = env.action_masks()
        env.step(int(mask.nonzero()[0][0]))
        m = env.mission
        assert len(m.path) == 2 and m.time_s > 0 and len(m.nis_log) == len(m.update_log) >= 1
        env.close()
