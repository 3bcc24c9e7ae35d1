"""Labelled sonar datasets at scale: ``mitsonar dataset CONFIG -o DIR [--workers N] [--address RAY]``.

`generate_dataset` renders a config's randomised samples (scenes, terrains, sonar settings,
poses, trajectories, materials, noise) on local processes or Ray actors into WebDataset shards with
a manifest, resumably and identically for any number of workers; `open_dataset` reads them back.
"""
from __future__ import annotations

from mitsonar.jobs.dataset.config import DatasetError, check_config, read_config
from mitsonar.jobs.dataset.runner import generate_dataset
from mitsonar.jobs.dataset.store import SonarDataset, open_dataset

__all__ = ["DatasetError", "SonarDataset", "check_config", "generate_dataset", "open_dataset", "read_config"]
