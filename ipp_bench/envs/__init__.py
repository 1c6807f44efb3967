"""Gymnasium environments and the registered benchmark tasks (``gym.make("ipp_bench/...")``)."""

from .graph import GraphIPPEnv
from .observation import GraphObservation
from .registry import (
    NAMESPACE,
    TASK_FILE_ERRORS,
    TASKS,
    TaskFileError,
    TaskSpec,
    load_task,
    make_env,
    parse_overrides,
    register_all,
    resolve_task,
    short_task_id,
    tagged,
    task_config,
    task_spec,
)

register_all()

__all__ = ["NAMESPACE", "GraphIPPEnv", "GraphObservation", "TASKS", "TASK_FILE_ERRORS", "TaskFileError", "TaskSpec",
           "load_task", "make_env", "parse_overrides", "register_all", "resolve_task", "short_task_id", "tagged",
           "task_config", "task_spec"]
