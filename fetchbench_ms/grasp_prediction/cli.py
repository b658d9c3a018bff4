"""``fetchbench grasps predict``: Contact-GraspNet's grasps on a suite task's observed target,
a sub-command of ``fetchbench grasps`` (the grasp labels) added by grasp prediction."""
from __future__ import annotations

from .show import add_predict_command


def add_commands(grasps_commands) -> None:
    """``grasps_commands``: the sub-commands of ``fetchbench grasps``."""
    add_predict_command(grasps_commands)
