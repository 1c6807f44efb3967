"""``benchmarks/joint_warm_start.py``'s checks, before its run folder (its fit: tests/policies)."""

import pytest
from lb_helpers import benchmark_script

pytest.importorskip("sb3_contrib")


def test_distill_refuses_a_teacher_without_a_policy_before_the_run_folder(tmp_path, capsys, monkeypatch):
    import ipp_bench.planners as planners

    # its checks register bench_teachers.py's probes: in a copy, so no later test's default planner list
    # (every registered planner) meets them
    monkeypatch.setattr(planners, "REGISTRY", dict(planners.REGISTRY))
    joint = benchmark_script("joint_warm_start")
    run = tmp_path / "run"
    # Grid15Train-v1 would be greedy's (no policy to distil) unless --teacher-for gives it a network
    with pytest.raises(SystemExit) as exit_:
        joint.main(["--distill", "--out", str(run), "--init", "ipp_bench/policies/checkpoints/attention_v6.pt",
                    "--tasks", "ipp_bench/Grid15Train-v1", "ipp_bench/Hotspots15Train-v2"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "'greedy' is a planner with no policy to distil" in err
    assert "Traceback" not in err and not run.exists()
