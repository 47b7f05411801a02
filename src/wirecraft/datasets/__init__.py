"""Demonstration datasets in the LeRobot v3 format: one schema for every data source.

- ``schema``: the features (``features_for``) and the data-source codes;
- ``recorder``: ``Episode`` and ``EpisodeRecorder`` (a running environment -> frames);
- ``writer``: ``EpisodeWriter`` (lerobot's create / add_frame / save_episode / finalize, with
  commits that survive a hard kill) and ``load_dataset``;
- ``collect``: scripted-expert demonstrations (``wirecraft collect``);
- ``importer``: a LeRobot dataset recorded elsewhere, converted (``wirecraft import``).

lerobot is imported only when a dataset is written or read.
"""

from wirecraft.datasets.recorder import Episode, EpisodeRecorder
from wirecraft.datasets.schema import SOURCES, features_for

__all__ = ["SOURCES", "Episode", "EpisodeRecorder", "features_for"]
