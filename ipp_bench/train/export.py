"""What leaves a run: its networks in the shipped checkpoint format, with what made them.

Every ``.pt`` a run writes (``warmstart/bc.pt``, ``export.pt``, ``last.pt``) goes through
:func:`ipp_bench.policies.checkpoint.save_checkpoint` with :func:`run_meta`: the exact command, the
settings, the seeds, the versions and the wall times. :func:`export_zip` turns one of a run's SB3
archives (``checkpoints/*.zip``) into the same format.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

from ipp_bench.policies.checkpoint import CheckpointError, save_checkpoint
from ipp_bench.train.archive import EXPECTED, attention_state_dict, check_attention_policy, read_archive
from ipp_bench.train.args import VAL_SEED0, TrainArgs, command_line, warm_start_seeds


def export_zip(zip_path: str | Path, out: str | Path | None = None) -> Path:
    """Convert an SB3 MaskablePPO archive of AttentionPolicy to the shipped ``.pt`` format.

    Reads the archive's JSON settings and its weights only (:mod:`ipp_bench.train.archive`): nothing
    in it is unpickled.

    Raises:
        CheckpointError: the file is missing or is not an SB3 archive of an AttentionPolicy.
    """
    from ipp_bench.policies.network import AttentionNet, NetConfig

    zip_path = Path(zip_path)
    data, weights = read_archive(zip_path)
    check_attention_policy(zip_path, data)
    kwargs = data.get("policy_kwargs")
    steps = data.get("num_timesteps")
    if not isinstance(kwargs, dict) or not isinstance(kwargs.get("net_config"), dict) or type(steps) is not int:
        raise CheckpointError(f"{zip_path}: its data has no net_config in policy_kwargs or no num_timesteps; "
                              f"expected {EXPECTED}")
    try:
        net = AttentionNet(NetConfig.from_dict(kwargs["net_config"]))
        net.load_state_dict(attention_state_dict(zip_path, weights))
    except (TypeError, ValueError, RuntimeError) as err:
        raise CheckpointError(f"{zip_path}: its weights do not fit the network its net_config describes "
                              f"({str(err).splitlines()[0]}); expected {EXPECTED}") from None
    return save_checkpoint(net.eval(), out or zip_path.with_suffix(".pt"),
                           meta={"source": str(zip_path), "ppo_steps": steps})


def versions() -> dict[str, str]:
    """Versions of what a checkpoint was trained with."""
    import platform

    import numpy as np
    import sb3_contrib
    import stable_baselines3
    import torch

    import ipp_bench

    return {"torch": str(torch.__version__), "stable_baselines3": str(stable_baselines3.__version__),
            "sb3_contrib": str(sb3_contrib.__version__), "numpy": str(np.__version__),
            "python": platform.python_version(), "ipp_bench": getattr(ipp_bench, "__version__", "")}


def run_meta(cfg: TrainArgs, state: Any, steps: int, val: dict[str, float]) -> dict[str, Any]:
    """The meta of a checkpoint written by a run at PPO step ``steps`` with validation figures ``val``
    (``state``: the run's :class:`~ipp_bench.train.run.RunState`)."""
    return {"task": cfg.task, "mix": list(cfg.mix), "ppo_steps": steps, "warm_start": cfg.warm_start,
            "warm_start_for": list(cfg.warm_start_for), "init": cfg.init,
            "command": command_line(cfg), "train_config": asdict(cfg) | {"out": ""},
            "seeds": {"seed": cfg.seed, "warm_start_episode_seeds": _warm_start_seeds(cfg),
                      "ppo_episode_seeds": "drawn by the environments' generators, seeded by --seed "
                                           "(SB3 set_random_seed)",
                      "validation_seeds": f"{VAL_SEED0}..{VAL_SEED0 + cfg.eval_episodes - 1} of "
                                          f"{', '.join(cfg.val_task or dict.fromkeys(cfg.tasks))}"},
            "versions": versions(), "device": cfg.device, "threads": cfg.threads,
            "ppo_wall_s": round(state.ppo_wall_s, 1), "warm_start_wall_s": round(state.bc_wall_s, 1), **val}


def _warm_start_seeds(cfg: TrainArgs) -> str:
    if cfg.warm_start == "none":
        return ""
    seeds = warm_start_seeds(cfg)
    if cfg.mix:
        return (f"{seeds.start}..{seeds.stop - 1}, each round's episodes split over {', '.join(cfg.tasks)} in turn "
                "(consecutive seeds)")
    return f"{seeds.start}..{seeds.stop - 1} of {cfg.task}"
