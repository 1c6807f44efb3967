"""Training the attention policy: ``ipp-bench train`` (needs the ``[train]`` extra).

- :mod:`~ipp_bench.train.args`: ``TrainArgs``, every setting of a run, the command line and its checks;
- :mod:`~ipp_bench.train.run`: the run folder, its state and resume;
- :mod:`~ipp_bench.train.command`: the command's entry point;
- :mod:`~ipp_bench.train.teachers`: the warm start's teachers and their checks;
- :mod:`~ipp_bench.train.warmstart` and :mod:`~ipp_bench.train.bc`: the DAgger warm start from
  roadmap planners (one or several tasks and teachers) and the behaviour-cloning fit;
- :mod:`~ipp_bench.train.ppo`: MaskablePPO with the attention policy, its after-update callback;
- :mod:`~ipp_bench.train.vec`: the training environments (reward, worker processes);
- :mod:`~ipp_bench.train.validation`: argmax episodes on held-out seeds, against greedy;
- :mod:`~ipp_bench.train.export`: checkpoints in the shipped format with what made them;
- :mod:`~ipp_bench.train.recipe`: a checkpoint's stages as data (``recipes/*.toml``), run by
  ``ipp-bench train --recipe NAME``.

The planners and the policy (:mod:`ipp_bench.planners`, :mod:`ipp_bench.policies`) never import
this package.
"""
