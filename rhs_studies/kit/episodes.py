"""The studies' episodes and scenes (:mod:`rhs_studies.episodes`, :mod:`rhs_studies.scenes`) and the environment of
a study's subprocesses (:mod:`rhs_studies.subprocess_env`)."""

from __future__ import annotations

from rhs_studies.episodes import (
    ANTENNAS,
    POLICY_HZ,
    add_episode_args,
    drive,
    make_paper_env,
    paper_slam_episode,
    start_study,
)
from rhs_studies.scenes import landmark_scene, typical_scene
from rhs_studies.subprocess_env import study_env

__all__ = ["ANTENNAS", "POLICY_HZ", "add_episode_args", "drive", "landmark_scene", "make_paper_env",
           "paper_slam_episode", "start_study", "study_env", "typical_scene"]
