"""Gymnasium environments and the registered benchmark tasks (``gym.make("ipp_bench/...")``)."""

from .graph import GraphIPPEnv
from .registry import TASKS, TaskSpec, register_all, tagged, task_spec

register_all()

__all__ = ["GraphIPPEnv", "TASKS", "TaskSpec", "register_all", "tagged", "task_spec"]
