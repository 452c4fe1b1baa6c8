"""Evaluation of a set of dances on 10-second segments, with the baselines of docs/evaluation.md.

A `Dance` is positions (T, 24, 3) at 30 fps plus its music (audio path, and the song time of frame 0).
Reference distribution for FID: the real Tang training dances (split.json); features are normalised with
the real validation dances' per-dimension statistics (both fixed, so every set is measured the same way).

Usage:
  ev = Evaluator.default()                               # loads the cache and split, fits the normaliser
  row = ev.evaluate([load_dance("gen/W_3.json"), ...])   # dict of metrics
  rows = ev.baselines()                                  # real, wrong music, frozen
"""
from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

from training.data import prepare
from training.data import skeleton as sk
from training.eval import features, metrics, music, tempo
from training.eval.data_checks import beat_phases

METRIC_KEYS = ("fid_k", "fid_g", "div_k", "div_g", "bas", "bas_chance", "lock_r", "lock_chance",
               "period_dev", "pfc", "jitter", "turn_rate", "spin", "foot_skate", "contact", "bone_err_mm",
               "bone_cv_pct", "segments")
SIMPLE_MULTIPLES = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
# A segment whose mean turn rate exceeds this spins (rad/s): the fastest of the 226 real Tang segments turns
# at 3.51, the median at 1.09 (the period lock once repeated a turn into minutes of 5-6 rad/s).
SPIN_RAD_S = 3.5


@dataclasses.dataclass
class Dance:
  name: str
  positions: np.ndarray          # (T, 24, 3) float64
  fps: float = 30.0
  audio_path: str = ""
  audio_offset_s: float = 0.0    # song time of frame 0
  style: str = ""

  def beats(self) -> np.ndarray:
    """Music beats on the dance's timeline (empty without audio)."""
    if not self.audio_path:
      return np.zeros(0)
    return music.beats_for_dance(self.audio_path, self.audio_offset_s)


def load_dance(path: str | pathlib.Path, audio: str | None = None, offset_s: float | None = None) -> Dance:
  """Reads a dance-motion/v1 JSON or a prepare-cache npz. The JSON may name its audio ("audio_path");
  `audio` / `offset_s` override what the file says."""
  path = pathlib.Path(path)
  if path.suffix == ".json":
    d = json.loads(path.read_text())
    if d.get("format") != "dance-motion/v1":
      raise ValueError(f"{path}: not a dance-motion/v1 file")
    if d.get("units", "m") != "m" or d.get("up_axis", "y") != "y":
      raise ValueError(f"{path}: expected metres and Y up")
    pos = np.asarray(d["positions"], dtype=np.float64)
    dance = Dance(path.stem, pos, float(d.get("fps", 30)), d.get("audio_path", ""),
                  float(d.get("audio_offset_s", 0.0)), d.get("style", ""))
  else:
    with np.load(path) as z:
      dance = Dance(path.stem, z["positions"].astype(np.float64), float(z["fps"]),
                    str(z["audio_path"]) if "audio_path" in z.files else "",
                    float(z["audio_offset_s"]) if "audio_offset_s" in z.files else 0.0,
                    str(z["style"]) if "style" in z.files else "")
  if dance.positions.ndim != 3 or dance.positions.shape[1:] != (24, 3):
    raise ValueError(f"{path}: positions must be (T, 24, 3), got {dance.positions.shape}")
  if abs(dance.fps - 30.0) > 1e-6:
    dance.positions = sk.resample(dance.positions, dance.fps, 30.0)
    dance.fps = 30.0
  if audio is not None:
    dance.audio_path = audio
  if offset_s is not None:
    dance.audio_offset_s = offset_s
  return dance


def cached_dances(ids: list[str]) -> list[Dance]:
  out = []
  for i in ids:
    m = prepare.load_motion(i)
    out.append(Dance(i, m["positions"].astype(np.float64), m["fps"], m["audio_path"], m["audio_offset_s"],
                     m["style"]))
  return out


def split_ids(part: str, tang_only: bool = True) -> list[str]:
  split = json.loads(prepare.SPLIT_PATH.read_text())
  return [i for i in split[part] if i.startswith("tang_") or not tang_only]


def segment_table(dances: list[Dance], beats_of=None) -> dict:
  """Features and per-segment metrics of every 10-s segment. beats_of(dance) -> beats on the dance's
  timeline (default: its own music)."""
  kin, geo, rows = [], [], []
  skel = sk.load_skeleton()
  n = int(features.SEGMENT_SECONDS * 30)
  for d in dances:
    beats = (beats_of or Dance.beats)(d)
    for k, seg in enumerate(features.segments(d.positions, d.fps)):
      kin.append(features.kinetic_features(seg, d.fps))
      geo.append(features.geometric_features(seg, d.fps))
      t0 = k * n / d.fps
      mb = metrics.motion_beats(seg, d.fps)
      b = metrics.beats_in_span(beats, t0, len(seg) / d.fps)
      row = {"dance": d.name, "start_s": t0, "pfc": metrics.pfc(seg, d.fps),
             "jitter": metrics.jitter(seg, d.fps), "foot_skate": metrics.foot_skating(seg, d.fps),
             "contact": metrics.contact_fraction(seg), "turn_rate": metrics.turn_rate(seg, d.fps)}
      row["spin"] = float(row["turn_rate"] > SPIN_RAD_S)
      row.update(metrics.bone_length_error(seg, skel.parents, skel.bone_lengths))
      if len(b) >= 2:
        row["bas"] = metrics.beat_align_score(b, mb)
        row["bas_chance"] = metrics.beat_align_chance(b, mb, seed=k)
      rows.append(row)
  return {"kinetic": np.array(kin), "geometric": np.array(geo), "rows": rows}


def beat_lock(dance: Dance, beats: np.ndarray) -> dict:
  """Whole-dance musicality that works for smooth (ballroom) motion.

  lock_r: |mean exp(2 pi i phase)| of the motion beats' phases in the music's beat grid (0 = unrelated,
    1 = always at the same phase); lock_chance = sqrt(pi / 4 / N), its mean for unrelated beats.
  period_dev: distance of the dominant motion period, in beats, from the nearest of SIMPLE_MULTIPLES,
    relative to that multiple (0 = on the grid; a period unrelated to the beat averages ~0.1).
  """
  dur = len(dance.positions) / dance.fps
  b = beats[(beats >= 0) & (beats < dur)]
  if len(b) < 4:
    return {}
  mb = metrics.motion_beats(dance.positions, dance.fps)
  ph = beat_phases(mb, b)
  out = {}
  if len(ph):
    out["lock_r"] = float(abs(np.exp(2j * np.pi * ph).mean()))
    out["lock_chance"] = float(np.sqrt(np.pi / 4 / len(ph)))
  period = tempo.dominant_period(dance.positions, dance.fps)
  ibi = float(np.polyfit(np.arange(len(b)), b, 1)[0])
  if np.isfinite(period):
    x = period / ibi
    out["period_dev"] = float(min(abs(x - m) / m for m in SIMPLE_MULTIPLES))
  return out


def on_real_spans(dances: list[Dance], real: list[Dance]) -> list[Dance]:
  """Each dance cut to the song time its real counterpart (same name) covers: from the real dance's
  audio_offset_s, as many frames as it has (fewer where the generated dance ends first). A generated dance
  covers the whole song, the real one a part of it (T_5_b: 26 s of a 109-s song), so the whole-song sets
  have about three times as many 10-s segments as the real validation, in other proportions per song; cut
  to the real spans both have the same segments, song for song, and a FID compares like with like."""
  by_name = {r.name: r for r in real}
  out = []
  for d in dances:
    if d.name not in by_name:
      raise ValueError(f"on_real_spans: no real dance named {d.name}")
    r = by_name[d.name]
    a = max(0, int(round((r.audio_offset_s - d.audio_offset_s) * d.fps)))
    out.append(Dance(d.name, d.positions[a:a + len(r.positions)], d.fps, d.audio_path,
                     d.audio_offset_s + a / d.fps, d.style))
  return out


class Evaluator:
  """Holds the reference (real training) features and the normaliser (real validation statistics)."""

  def __init__(self, reference: list[Dance], validation: list[Dance]):
    self.validation = validation
    ref = segment_table(reference, beats_of=lambda d: np.zeros(0))
    val = segment_table(validation, beats_of=lambda d: np.zeros(0))
    self.norm_k = metrics.FeatureStats.fit(val["kinetic"])
    # Geometric features are fractions of a segment: no dimension counts as varying less than 5 %.
    self.norm_g = metrics.FeatureStats.fit(val["geometric"], floor=0.05)
    self.ref_rows = ref["rows"]  # which dance each reference segment is from
    self.ref_k = self.norm_k.apply(ref["kinetic"])
    self.ref_g = self.norm_g.apply(ref["geometric"])

  @classmethod
  def default(cls) -> "Evaluator":
    return cls(cached_dances(split_ids("train")), cached_dances(split_ids("validation")))

  def evaluate(self, dances: list[Dance], beats_of=None) -> dict:
    t = segment_table(dances, beats_of)
    k = self.norm_k.apply(t["kinetic"])
    g = self.norm_g.apply(t["geometric"])
    rows = t["rows"]
    per_dance = [beat_lock(d, (beats_of or Dance.beats)(d)) for d in dances]

    def mean(key, rows=rows):
      v = [r[key] for r in rows if key in r and np.isfinite(r[key])]
      return float(np.mean(v)) if v else float("nan")
    return {"fid_k": metrics.frechet_distance(self.ref_k, k), "fid_g": metrics.frechet_distance(self.ref_g, g),
            "div_k": metrics.diversity(k), "div_g": metrics.diversity(g), "bas": mean("bas"),
            "bas_chance": mean("bas_chance"), "lock_r": mean("lock_r", per_dance),
            "lock_chance": mean("lock_chance", per_dance), "period_dev": mean("period_dev", per_dance),
            "pfc": mean("pfc"), "jitter": mean("jitter"), "turn_rate": mean("turn_rate"), "spin": mean("spin"),
            "foot_skate": mean("foot_skate"), "contact": mean("contact"), "bone_err_mm": mean("bone_err_mm"),
            "bone_cv_pct": mean("bone_cv_pct"), "segments": len(rows)}

  def fid_div(self, dances: list[Dance]) -> dict:
    """FID_k, FID_g, Div_k, Div_g and the segment count alone (no beats: needs no music analysis)."""
    t = segment_table(dances, beats_of=lambda d: np.zeros(0))
    k, g = self.norm_k.apply(t["kinetic"]), self.norm_g.apply(t["geometric"])
    return {"fid_k": metrics.frechet_distance(self.ref_k, k), "fid_g": metrics.frechet_distance(self.ref_g, g),
            "div_k": metrics.diversity(k), "div_g": metrics.diversity(g), "segments": len(k)}

  def baselines(self) -> dict[str, dict]:
    val = self.validation
    n = len(val)
    # Wrong music: dance i against the beats of validation song i + 1 (from that song's own dance start).
    wrong = {d.name: val[(i + 1) % n] for i, d in enumerate(val)}
    frozen = [Dance(d.name, np.repeat(d.positions[:1], len(d.positions), axis=0), d.fps, d.audio_path,
                    d.audio_offset_s, d.style) for d in val]
    return {"real (validation)": self.evaluate(val),
            "real, wrong music": self.evaluate(val, beats_of=lambda d: wrong[d.name].beats()),
            "frozen pose": self.evaluate(frozen)}


def markdown_table(rows: dict[str, dict]) -> str:
  head = "| set | " + " | ".join(METRIC_KEYS) + " |\n|---|" + "---|" * len(METRIC_KEYS) + "\n"
  lines = []
  for name, r in rows.items():
    cells = [f"{r[k]:.0f}" if k == "segments" else f"{r[k]:.3g}" for k in METRIC_KEYS]
    lines.append(f"| {name} | " + " | ".join(cells) + " |")
  return head + "\n".join(lines) + "\n"
