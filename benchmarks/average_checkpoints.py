"""Average two attention checkpoints of the same network in weight space (issue 17).

``w * A + (1 - w) * B`` parameter by parameter, written with ``save_checkpoint`` and a meta that
names both inputs and keeps ``A``'s stages with this one appended. Made for a network fine-tuned
from another (``attention_v4.pt`` from ``attention_v3.pt``): the average keeps part of what the
fine-tuning moved away from (``benchmarks/RESULTS.md``, "Attention at the frontier, fourth session").

    python benchmarks/average_checkpoints.py ipp_bench/policies/checkpoints/attention_v4.pt \\
        ipp_bench/policies/checkpoints/attention_v3.pt --weight 0.7 --out runs/soup70.pt
"""

from __future__ import annotations

import argparse
import copy
import shlex
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", type=Path, help="checkpoint A (its meta and stages are kept)")
    ap.add_argument("b", type=Path, help="checkpoint B, the same network shape as A")
    ap.add_argument("--weight", type=float, required=True, help="A's weight w in [0, 1]; B's is 1 - w")
    ap.add_argument("--out", type=Path, required=True, help="the averaged checkpoint (.pt; a .json beside it)")
    args = ap.parse_args(argv)
    if not 0.0 <= args.weight <= 1.0:
        ap.error(f"--weight {args.weight}: must be within [0, 1]")
    for name, path in (("A", args.a), ("B", args.b)):
        if not path.is_file():
            ap.error(f"{name} {path}: not found")
    if args.out.suffix != ".pt":
        ap.error(f"--out {args.out}: expected a .pt file name")

    from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
    from ipp_bench.policies.network import AttentionEnsemble

    try:
        net_a, meta_a = load_checkpoint(args.a)
        net_b, _ = load_checkpoint(args.b)
    except CheckpointError as err:
        ap.error(str(err))
    for name, path, net in (("A", args.a, net_a), ("B", args.b, net_b)):
        if isinstance(net, AttentionEnsemble):
            ap.error(f"{name} {path}: an ensemble of {len(net.members)} networks; average single networks")
    if net_a.cfg.to_dict() != net_b.cfg.to_dict():
        ap.error(f"{args.a} and {args.b} are different networks ({net_a.cfg.to_dict()} and {net_b.cfg.to_dict()})")
    sa, sb = net_a.state_dict(), net_b.state_dict()
    w = args.weight
    net_a.load_state_dict({k: w * v + (1.0 - w) * sb[k] if v.is_floating_point() else v for k, v in sa.items()})
    command = "python benchmarks/average_checkpoints.py " + shlex.join(argv if argv is not None else sys.argv[1:])
    meta = copy.deepcopy(meta_a)
    stages = list(meta.get("stages", []))
    stages.append({"stage": len(stages) + 1, "command": command,
                   "what": f"weight average: {w:g} x {args.a.name} + {1.0 - w:g} x {args.b.name}"})
    meta.update({"stages": stages, "command": command, "phase": "weight average",
                 "average": {"a": str(args.a), "b": str(args.b), "weight_a": w}})
    meta = {k: v for k, v in meta.items() if not k.startswith("val/")}  # A's validation is not the average's
    save_checkpoint(net_a, args.out, meta=meta)
    print(f"wrote {args.out}: {w:g} x {args.a} + {1.0 - w:g} x {args.b}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
