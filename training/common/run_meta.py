"""What a run writes into its exported model besides the tensors, and the per-run constants it measures once:
the time base (fixed-rate, or tempo-normalised with each style's reference tempo and dance period, the bar
clock, the tempo fold, the period lock's defaults) and the sampling defaults (style and music guidance).

    refs = style_refs_of(config, run, log)        # {"waltz": 87.0, ...}, kept in <run>/style_reference_bpm.json
    meta = {"time_base": time_base_meta(config, run, log), "sampling": sampling_meta(config)}

The measured constants are computed from the training songs the first time and then read from the run
directory, so every stage of a run (and a resumed run) uses the same values. docs/model.md sections 1 and 6
describe the metadata's keys.
"""
from __future__ import annotations

import json
import pathlib

from training.common import clips as td
from training.run_config import RunConfig


def style_refs_of(config: RunConfig, run: pathlib.Path, log) -> dict[str, float] | None:
  """Per-style reference tempi of a tempo-normalised run (None for a fixed-rate run), computed once from
  the training songs and kept in <run>/style_reference_bpm.json (the export writes them into the model)."""
  if config.tempo_ref <= 0:
    return None
  path = run / "style_reference_bpm.json"
  if path.is_file():
    return json.loads(path.read_text())
  split = td.load_split()
  # Every style row gets a reference, also a style whose songs all validate (AIST++'s test list).
  refs = td.style_reference_tempi(td.paired_ids(split["train"]), config.tempo_ref, td.run_styles(split))
  log(f"style reference tempi (BPM): {json.dumps(refs)}")
  run.mkdir(parents=True, exist_ok=True)
  path.write_text(json.dumps(refs))
  return refs


def dance_periods_of(config: RunConfig, run: pathlib.Path, log) -> dict[str, int]:
  """Each style's dance period in beats on the tempo-normalised timeline (clips.dance_period_beats),
  measured once on the training dances and kept in <run>/dance_period_beats.json; the export writes it into
  the model for the engine's period lock."""
  path = run / "dance_period_beats.json"
  if path.is_file():
    return json.loads(path.read_text())
  periods = td.dance_period_beats(td.paired_ids(td.load_split()["train"]), style_refs_of(config, run, log))
  log(f"dance periods (beats): {json.dumps(periods)}")
  path.write_text(json.dumps(periods))
  return periods


def warp_tag(refs: dict[str, float], bar_clock: dict | None = None, fold_tempo: bool = False) -> str:
  """The token caches' name for a tempo-normalised timeline: the reference tempi, the bar clock's metres, the
  fold (a cache made for other settings is never read)."""
  tag = "warp_" + "_".join(f"{refs[s]:g}" for s in sorted(refs))
  if bar_clock:
    tag += "_bar" + "_".join(str(td.bar_beats_of(s, bar_clock)) for s in sorted(refs))
  return tag + ("_fold" if fold_tempo else "")


def fold_tempo_of(config: RunConfig) -> bool:
  """A tempo-normalised run with --fold-tempo: the tempo features folded to the style's reference."""
  return config.tempo_ref > 0 and config.fold_tempo


def bar_clock_of(config: RunConfig) -> dict | None:
  """The bar clock of a tempo-normalised run with --bar-clock (None otherwise)."""
  return td.BAR_CLOCK if config.tempo_ref > 0 and config.bar_clock else None


def time_base_meta(config: RunConfig, run: pathlib.Path, log) -> dict:
  """The exported model's time_base metadata (docs/model.md sections 1 and 6): fixed-rate, or tempo-normalised
  with the style reference tempi, the bar clock if on, the dance periods and the period lock's default weight,
  per-style weights, kernel sharpness and reach (periods back per stream)."""
  if config.tempo_ref <= 0:
    return {"kind": "fixed"}
  tb = {"kind": "tempo", "reference_bpm": float(config.tempo_ref),
        "style_reference_bpm": style_refs_of(config, run, log)}
  if bar_clock_of(config):
    tb["bar_clock"] = bar_clock_of(config)
  if fold_tempo_of(config):
    tb["fold_tempo"] = True
  tb["dance_period_beats"] = dance_periods_of(config, run, log)
  tb["period_lock"] = float(config.period_lock)
  tb["period_lock_sharpness"] = float(config.period_lock_sharpness)
  if config.style_period_lock:
    tb["style_period_lock"] = {name: float(b) for name, b in config.style_period_lock.items()}
  periods = config.period_lock_periods
  tb["period_lock_periods"] = {"upper": int(periods[0]), "lower": int(periods[1])}
  return tb


def sampling_meta(config: RunConfig) -> dict:
  """The exported file's sampling defaults (metadata "sampling"; docs/model.md section 6): the style guidance
  weight, the music guidance weight when it is not 1 (off), and the feature columns the music dropout
  replaced when it replaced only some (music_guidance_features: the engine's music-mean lanes replace the
  same)."""
  meta = {"guidance": float(config.guidance)}
  music = float(config.music_guidance)
  if music != 1.0:
    meta["music_guidance"] = music
  ranges = config.music_dropout_features
  if ranges and float(config.music_dropout) > 0:
    meta["music_guidance_features"] = [[int(b), int(e)] for b, e in ranges]
  return meta
