"""The data stage: the motion cache (training/cache/motion, training.data.prepare) when it is missing. The
music features are extracted later, by the stages that read them (cached per song and tool binary)."""
from __future__ import annotations

from training.common import clips as td
from training.run_config import RunConfig


def run(config: RunConfig, log) -> None:
  del config, log  # the cache does not depend on the run
  td.ensure_motion_cache()
