"""Put several attention checkpoints of one network shape into one ensemble checkpoint (issue 17).

The ensemble (:class:`ipp_bench.policies.network.AttentionEnsemble`) decides by the mean of its
members' log-probabilities; the ``attention`` planner, ``validate_checkpoints.py`` and a warm start's
teacher (``attention:checkpoint=ENSEMBLE.pt``) read it like any checkpoint; training refuses it as
``--init``. Each decision costs one forward pass per member (``benchmarks/RESULTS.md``, issue 17,
twelfth session: why it is a teacher, not the default).

    python benchmarks/ensemble_checkpoints.py ipp_bench/policies/checkpoints/attention_v6.pt \\
        runs/ei/v6s1/warmstart/bc.pt --out runs/ens/v6_s1.pt
"""

from __future__ import annotations

import argparse
import hashlib
import shlex
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    from ipp_bench.policies.network import MAX_MEMBERS

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("members", nargs="+", type=Path, help=f"2 to {MAX_MEMBERS} single-network checkpoints (.pt)")
    ap.add_argument("--out", type=Path, required=True, help="the ensemble checkpoint (.pt; a .json beside it)")
    args = ap.parse_args(argv)
    if not 2 <= len(args.members) <= MAX_MEMBERS:
        ap.error(f"{len(args.members)} checkpoints given: an ensemble holds 2 to {MAX_MEMBERS}")
    for path in args.members:
        if not path.is_file():
            ap.error(f"{path}: not found")
    if args.out.suffix != ".pt":
        ap.error(f"--out {args.out}: expected a .pt file name")

    from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
    from ipp_bench.policies.network import AttentionEnsemble

    nets, described = [], []
    for path in args.members:
        try:
            net, meta = load_checkpoint(path)
        except CheckpointError as err:
            ap.error(str(err))
        if isinstance(net, AttentionEnsemble):
            ap.error(f"{path}: already an ensemble of {len(net.members)} networks; name its members instead")
        if nets and net.cfg != nets[0].cfg:
            ap.error(f"{path} is a different network ({net.cfg.to_dict()}) from {args.members[0]} "
                     f"({nets[0].cfg.to_dict()})")
        nets.append(net)
        described.append({"path": str(path), "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                          "command": meta.get("command"), "stages": meta.get("stages"),
                          "ppo_steps": meta.get("ppo_steps")})
    command = "python benchmarks/ensemble_checkpoints.py " + shlex.join(argv if argv is not None else sys.argv[1:])
    meta = {"phase": "ensemble", "command": command, "members": described,
            "what": f"the mean log-probability of {len(nets)} networks"}
    save_checkpoint(AttentionEnsemble(nets), args.out, meta=meta)
    print(f"wrote {args.out}: an ensemble of {len(nets)} networks")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
