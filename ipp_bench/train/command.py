"""``ipp-bench train``'s entry point: one run (:mod:`~ipp_bench.train.run`), a recipe's stages
(:mod:`~ipp_bench.train.recipe`), ``--export`` or ``--validate``."""

from __future__ import annotations

import argparse
import sys

from ipp_bench.train.args import add_train_arguments, explicit
from ipp_bench.train.run import execute, resolve_config, set_threads


def run_train(args: argparse.Namespace) -> int:
    """Run ``ipp-bench train`` with parsed arguments; returns the exit code."""
    from ipp_bench.policies.checkpoint import CheckpointError

    def error(msg: str) -> int:
        print(f"ipp-bench train: error: {msg}", file=sys.stderr)
        return 2

    if (args.dry_run or args.from_stage) and not args.recipe:
        return error(f"{'--dry-run' if args.dry_run else '--from-stage'} needs --recipe NAME")
    if args.recipe:
        from ipp_bench.train.recipe import run_recipe_command

        return run_recipe_command(args)
    if args.export:
        from ipp_bench.train.export import export_zip

        try:
            path = export_zip(args.export)
        except CheckpointError as err:
            return error(f"--export {err}")
        print(f"wrote {path}")
        return 0
    if args.validate:
        from ipp_bench.train.validation import DEFAULT_VALIDATION_TASKS, validate_checkpoints

        set_threads(args.threads or 0)
        episodes = args.eval_episodes if args.eval_episodes is not None else 16
        if episodes < 1:
            return error(f"--eval-episodes {episodes} is invalid: expected an integer >= 1")
        return validate_checkpoints(args.validate, args.val_task or list(DEFAULT_VALIDATION_TASKS), episodes,
                                    args.json)
    try:
        cfg, run = resolve_config(explicit(args), args.resume)
    except ValueError as err:
        return error(str(err))
    return execute(cfg, run)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ipp-bench train",
                                     description="train the attention policy (DAgger warm start + MaskablePPO)")
    add_train_arguments(parser)
    return run_train(parser.parse_args(argv))


__all__ = ["add_train_arguments", "main", "run_train"]
