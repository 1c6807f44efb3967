"""Evaluation: the episode runner, the leaderboard and its executors."""
