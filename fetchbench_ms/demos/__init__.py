"""The Fetch dataset: expert demonstrations in ManiSkill's trajectory format (docs/demos.md)."""
from .generate import DemoJob, generate, merge, suite_task_ids

__all__ = ["DemoJob", "generate", "merge", "suite_task_ids"]
