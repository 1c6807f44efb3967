"""Evaluation: the episode runner, the leaderboard, its results folder, its report and its executors.

- one episode: ``runner`` (by task id and planner spec), ``figure`` (its PNG), ``demo`` (the MuJoCo video);
- a leaderboard run: ``plan`` (arguments, seeds), ``fingerprint`` (what decides the numbers),
  ``against`` (pairing with a published board), ``verify`` (a published board checked before it is
  used), ``leaderboard`` (runs the episodes);
- its folder: ``results`` (lock, resume, append), ``run_json``, ``results_csv``, ``machine``;
- where episodes run: ``executors`` (serial, process pool), ``ray_executor``, ``ray_watchdog``
  (run as ``python -m``), ``jobs`` (what every backend shares);
- the report, a pure function of results.csv: ``report`` (``leaderboard.md`` and its files),
  ``tables`` (rows grouped), ``markdown``, ``markdown_stats``, ``plots``; the statistics:
  ``aggregate`` (scores over tasks, rliable's definitions) and ``power`` (episodes a board needs).
"""
