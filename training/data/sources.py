"""Converters from each motion source to the canonical SMPL-24 skeleton at 30 fps (docs/data.md).

Every converter returns a `Motion`: positions (T, 24, 3) float32 in metres, Y up, on the canonical bone
lengths, feet on the floor (y = 0 is the lowest foot joint's level), at 30 fps. The joint identification of
Tang 2018's 23 points is documented (with the evidence) in docs/data.md.
"""
from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

from training.data import bvh as bvh_lib
from training.data import skeleton as sk
from training.data.skeleton import J

TANG_FPS = 25.0
TANG_STYLES = {"C": "cha-cha", "R": "rumba", "T": "tango", "W": "waltz"}

# Tang 2018 point indices (identified by plotting; docs/data.md). "Left" is the dancer's left.
TANG = dict(head_a=0, head_b=1, spine=2,
            r_shoulder=3, r_elbow=4, r_forearm=5, r_wrist=6, r_hand=22,
            r_hip=7, r_knee=8, r_ankle=9, r_heel=10, r_toe=11,
            l_shoulder=12, l_elbow=13, l_marker_a=14, l_wrist=15, l_marker_b=21,
            l_hip=16, l_knee=17, l_ankle=18, l_heel=19, l_toe=20)


@dataclasses.dataclass
class Motion:
  positions: np.ndarray          # (T, 24, 3) float32
  fps: float
  style: str
  source: str
  audio_path: str = ""
  audio_offset_s: float = 0.0    # song time of frame 0
  notes: dict = dataclasses.field(default_factory=dict)


def _leg_length(hip, knee, ankle) -> float:
  return float(np.median(np.linalg.norm(knee - hip, axis=-1) + np.linalg.norm(ankle - knee, axis=-1)))


def _finish(src_root, points, frames, skel, src_leg) -> np.ndarray:
  """Retargets, scales the root path by the canonical/source leg-length ratio, puts the feet on the floor."""
  canon_leg = float(skel.bone_lengths[J["left_knee"]] + skel.bone_lengths[J["left_ankle"]])
  root = src_root * (canon_leg / src_leg)
  pos = sk.retarget(points, root, skel, frames)
  return sk.put_on_floor(pos)


def _trunk_frames(l_hip, r_hip, spine_low, l_sh, r_sh, spine_high):
  """Pelvis frame for the bones leaving the pelvis; torso frame for the spine, neck, collars, shoulders."""
  hip_mid = 0.5 * (l_hip + r_hip)
  sh_mid = 0.5 * (l_sh + r_sh)
  pelvis = sk.body_frame(l_hip, r_hip, hip_mid, spine_low)
  torso = sk.body_frame(l_sh, r_sh, spine_high, sh_mid)
  frames = {J["left_hip"]: pelvis, J["right_hip"]: pelvis, J["spine1"]: pelvis}
  for name in ("spine2", "spine3", "neck", "left_collar", "right_collar", "left_shoulder",
               "right_shoulder"):
    frames[J[name]] = torso
  return frames


# The two readings of the Tang dancer's sides (docs/data.md "Left vs right"). "captured": points 12-20 are the
# left side and the coordinates are taken as they are (the extended arm of the hold is then the left: a
# man's hold with a lady's head and top line). "lady": points 3-11 are the left side and the capture is
# mirrored (x negated), which keeps the toes ahead of the heels: the lady's part, her right arm extended,
# her head turned and tilted to her left. The cues decide for "lady"; the cache and the shipped model still
# use "captured" until the model is retrained on it (the retrain command is in docs/data.md).
TANG_SIDES = ("captured", "lady")
TANG_SIDES_DEFAULT = "captured"


def _tang_point_map(sides: str) -> dict[str, int]:
  if sides == "captured":
    return TANG
  swap = {"l_": "r_", "r_": "l_"}
  return {(swap[k[:2]] + k[2:] if k[:2] in swap else k): i for k, i in TANG.items()}


def convert_tang(folder: pathlib.Path, skel: sk.Skeleton, sides: str = TANG_SIDES_DEFAULT) -> Motion:
  """One Tang take on the canonical skeleton; `sides`: one of TANG_SIDES (above)."""
  if sides not in TANG_SIDES:
    raise ValueError(f"convert_tang: sides must be one of {TANG_SIDES}, got {sides!r}")
  z = np.load(folder / "motion.npz")
  cfg = json.loads((folder / "config.json").read_text())
  s = z["skeletons"].astype(np.float64) * 0.01   # cm -> m, root-relative
  c = z["center"].astype(np.float64) * 0.01      # global root position
  if sides == "lady":
    s[..., 0] = -s[..., 0]
    c[..., 0] = -c[..., 0]
  g = s + c[:, None]
  g, n_spikes = sk.remove_spikes(g, threshold=0.05)
  # config.json says the dance covers song frames start..end at 25 fps, but most takes hold 0.1-2 % fewer
  # frames than that span. Spreading the frames over the stated span (effective rate 25 * T / span)
  # brings the motion's period closer to whole beats and halves its phase drift against the beats
  # (docs/data.md, "Alignment"), so the take is timed by the config, not by a nominal 25 fps.
  span = cfg["end_position"] - cfg["start_position"]
  fps_in = TANG_FPS * s.shape[0] / span if span > 0 else TANG_FPS
  g = sk.resample(g, fps_in, sk.FPS)
  p = {k: g[:, i] for k, i in _tang_point_map(sides).items()}
  root = sk.resample(c, fps_in, sk.FPS)
  head = 0.5 * (p["head_a"] + p["head_b"])
  sh_mid = 0.5 * (p["l_shoulder"] + p["r_shoulder"])
  points = {}
  for side in "lr":
    name = "left" if side == "l" else "right"
    points[J[f"{name}_hip"]] = p[f"{side}_hip"]
    points[J[f"{name}_knee"]] = p[f"{side}_knee"]
    points[J[f"{name}_ankle"]] = p[f"{side}_ankle"]
    points[J[f"{name}_foot"]] = p[f"{side}_toe"]
    points[J[f"{name}_shoulder"]] = p[f"{side}_shoulder"]
    points[J[f"{name}_elbow"]] = p[f"{side}_elbow"]
    points[J[f"{name}_wrist"]] = p[f"{side}_wrist"]
    # The hand continues the forearm: the left arm's distal markers are not a consistent hand point.
    points[J[f"{name}_hand"]] = 2 * p[f"{side}_wrist"] - p[f"{side}_elbow"]
  points[J["neck"]] = sh_mid
  points[J["head"]] = head
  frames = _trunk_frames(p["l_hip"], p["r_hip"], p["spine"], p["l_shoulder"], p["r_shoulder"], p["spine"])
  leg = 0.5 * (_leg_length(p["l_hip"], p["l_knee"], p["l_ankle"]) +
               _leg_length(p["r_hip"], p["r_knee"], p["r_ankle"]))
  pos = _finish(root, points, frames, skel, leg)
  style = TANG_STYLES[folder.name.split("_")[1]]
  return Motion(pos.astype(np.float32), sk.FPS, style, "tang2018",
                audio_path=str(folder / "audio.ogg"),
                audio_offset_s=cfg["start_position"] / TANG_FPS,
                notes={"spikes_removed": n_spikes, "source_frames": int(s.shape[0]), "source_fps": fps_in,
                       "config": cfg, "tang_sides": sides})


# BVH joint names -> SMPL joints. "_end" are end sites.
CMU_MAP = dict(pelvis="hip", spine_low="abdomen", spine_high="chest", neck="neck", head="head",
               l_hip="lThigh", l_knee="lShin", l_ankle="lFoot", l_toe="lFoot_end",
               l_shoulder="lShldr", l_elbow="lForeArm", l_wrist="lHand", l_hand="lMid1",
               r_hip="rThigh", r_knee="rShin", r_ankle="rFoot", r_toe="rFoot_end",
               r_shoulder="rShldr", r_elbow="rForeArm", r_wrist="rHand", r_hand="rMid1")
PERFUME_MAP = dict(pelvis="Hips", spine_low="Chest", spine_high="Chest3", neck="Neck", head="Head",
                   l_hip="LeftHip", l_knee="LeftKnee", l_ankle="LeftAnkle", l_toe="LeftToe",
                   l_shoulder="LeftShoulder", l_elbow="LeftElbow", l_wrist="LeftWrist",
                   l_hand="LeftWrist_end",
                   r_hip="RightHip", r_knee="RightKnee", r_ankle="RightAnkle", r_toe="RightToe",
                   r_shoulder="RightShoulder", r_elbow="RightElbow", r_wrist="RightWrist",
                   r_hand="RightWrist_end")


def convert_bvh(path: pathlib.Path, mapping: dict, unit_scale: float, style: str, source: str,
                skel: sk.Skeleton) -> Motion:
  b = bvh_lib.read_bvh(path)
  g = b.global_positions() * unit_scale
  # Some takes (Perfume) open with a rest-pose frame somewhere else on the stage: drop leading frames
  # after which the root jumps farther than any dancer moves in one frame.
  dropped = 0
  while g.shape[0] > 2 and np.linalg.norm(g[1, 0] - g[0, 0]) > 0.3:
    g = g[1:]
    dropped += 1
  fps_in = b.fps
  if abs(fps_in - sk.FPS) > 0.05:
    g = sk.resample(g, fps_in, sk.FPS)
  p = {k: g[:, b.index(v)] for k, v in mapping.items()}
  points = {J["neck"]: p["neck"], J["head"]: p["head"]}
  for side in "lr":
    name = "left" if side == "l" else "right"
    for part, key in (("hip", "hip"), ("knee", "knee"), ("ankle", "ankle"), ("foot", "toe"),
                      ("shoulder", "shoulder"), ("elbow", "elbow"), ("wrist", "wrist"),
                      ("hand", "hand")):
      points[J[f"{name}_{part}"]] = p[f"{side}_{key}"]
  frames = _trunk_frames(p["l_hip"], p["r_hip"], p["spine_low"], p["l_shoulder"], p["r_shoulder"],
                         p["spine_high"])
  leg = 0.5 * (_leg_length(p["l_hip"], p["l_knee"], p["l_ankle"]) +
               _leg_length(p["r_hip"], p["r_knee"], p["r_ankle"]))
  pos = _finish(p["pelvis"], points, frames, skel, leg)
  return Motion(pos.astype(np.float32), sk.FPS, style, source,
                notes={"source_fps": fps_in, "source_frames": int(b.motion.shape[0]),
                       "leading_frames_dropped": dropped})
