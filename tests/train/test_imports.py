"""The planners and the policy never import the training code (it needs stable-baselines3 and writes
run folders; a leaderboard or a deployment loads a checkpoint without it)."""

import subprocess
import sys


def test_planners_and_policies_do_not_import_training():
    code = ("import sys, ipp_bench.planners, ipp_bench.policies, ipp_bench.policies.planner, "
            "ipp_bench.policies.checkpoint, ipp_bench.policies.sb3; "
            "from ipp_bench.planners import make_planner; make_planner('attention'); "
            "print([m for m in sys.modules if m.startswith('ipp_bench.train')])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
