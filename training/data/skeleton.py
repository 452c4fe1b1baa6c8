"""The canonical 24-joint SMPL skeleton and the geometry every data source is converted with.

Conventions (docs/data.md): global joint positions in metres, Y up, right-handed. In the rest pose the body
faces +Z and its left side is +X (SMPL's convention: the left hip's rest offset has x > 0).

Usage:
  skel = load_skeleton()
  positions = retarget(source_points, skel, frame_bones=...)   # (T, 24, 3) on the canonical lengths
"""
from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

SHARED_DATA = pathlib.Path(__file__).resolve().parents[3] / "shared" / "data"
SKELETON_PATH = SHARED_DATA / "skeleton" / "smpl24_skeleton.json"
FPS = 30

JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand")
J = {name: i for i, name in enumerate(JOINT_NAMES)}
UPPER_JOINTS = (3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23)  # 15
LOWER_JOINTS = (0, 1, 2, 4, 5, 7, 8, 10, 11)  # 9
LEFT_JOINTS = tuple(i for i, n in enumerate(JOINT_NAMES) if n.startswith("left_"))
RIGHT_JOINTS = tuple(i for i, n in enumerate(JOINT_NAMES) if n.startswith("right_"))
FOOT_JOINTS = (7, 8, 10, 11)  # ankles and feet (toes): the joints that touch the floor
# Joint j of a mirrored body is joint MIRROR[j] of the original (left and right swapped, the rest kept).
MIRROR = tuple(J[n.replace("left_", "right_")] if n.startswith("left_") else
               J[n.replace("right_", "left_")] if n.startswith("right_") else i for i, n in enumerate(JOINT_NAMES))


def mirror_positions(positions: np.ndarray, skel: "Skeleton | None" = None) -> np.ndarray:
  """(..., 24, 3) -> the same motion reflected through the body's sagittal plane x = 0 (x negated) with
  left and right swapped: a dance turning left becomes one turning right, still on Y up, facing +Z at rest
  with its left at +X. The canonical left and right bones differ by up to 1 cm, so the result is put back on
  `skel`'s lengths (default: the canonical skeleton). Training augmentation (training.train --mirror)."""
  out = np.asarray(positions, dtype=np.float64)[..., list(MIRROR), :].copy()
  out[..., 0] = -out[..., 0]
  return project_bone_lengths(out, skel if skel is not None else load_skeleton())


@dataclasses.dataclass(frozen=True)
class Skeleton:
  """Parents (24,) int, rest offsets (24, 3) metres relative to the parent, bone lengths (24,)."""
  parents: np.ndarray
  offsets: np.ndarray

  @property
  def bone_lengths(self) -> np.ndarray:
    return np.linalg.norm(self.offsets, axis=-1)

  def rest_positions(self) -> np.ndarray:
    """Global rest-pose joint positions (24, 3), pelvis at the origin."""
    out = np.zeros((24, 3))
    for j in range(1, 24):
      out[j] = out[self.parents[j]] + self.offsets[j]
    return out

  def as_json(self) -> dict:
    return {"joint_names": list(JOINT_NAMES), "parents": self.parents.tolist(),
            "rest_offsets": self.offsets.tolist()}


def load_skeleton(path: str | pathlib.Path = SKELETON_PATH) -> Skeleton:
  with open(path) as f:
    d = json.load(f)
  parents = np.asarray(d["smpl_parents"], dtype=np.int64)
  offsets = np.asarray(d["smpl_offsets"], dtype=np.float64)
  assert parents.shape == (24,) and offsets.shape == (24, 3)
  for j in range(1, 24):
    assert 0 <= parents[j] < j, "parents must precede children"
  return Skeleton(parents, offsets)


def _unit(v: np.ndarray, eps: float = 1e-9) -> np.ndarray:
  return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), eps)


def body_frame(left: np.ndarray, right: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
  """Rotation matrices (T, 3, 3) whose columns are the body's (left, up, forward) axes.

  x = left - right; y = high - low made orthogonal to x; z = x cross y (forward, right-handed).
  Applied to a rest offset (which is expressed with the body facing +Z, left = +X), it poses that offset.
  """
  x = _unit(left - right)
  y = high - low
  y = _unit(y - (y * x).sum(-1, keepdims=True) * x)
  z = np.cross(x, y)
  return np.stack([x, y, z], axis=-1)


def retarget(points: dict[int, np.ndarray], root: np.ndarray, skel: Skeleton,
             frames: dict[int, np.ndarray]) -> np.ndarray:
  """Builds canonical-length positions (T, 24, 3) from source joint estimates, bone by bone.

  points: SMPL joint index -> (T, 3) source position of that joint; for a bone parent -> child whose child
    is in `points` (and parent too), the posed bone direction is points[child] - points[parent].
  frames: SMPL joint index (child) -> (T, 3, 3) body frame; that bone's direction is frame @ rest offset
    (used for the short trunk bones whose source estimates are unreliable).
  root: (T, 3) pelvis position. Every bone gets the canonical length, so bone lengths are exact.
  """
  t = root.shape[0]
  out = np.zeros((t, 24, 3))
  out[:, 0] = root
  lengths = skel.bone_lengths
  for j in range(1, 24):
    p = skel.parents[j]
    if j in frames:
      d = np.einsum("tij,j->ti", frames[j], skel.offsets[j])
    else:
      d = points[j] - points[p]
    out[:, j] = out[:, p] + lengths[j] * _unit(d)
  return out


def project_bone_lengths(positions: np.ndarray, skel: Skeleton) -> np.ndarray:
  """Places every child at parent + length * normalize(child - parent), walking down from the pelvis."""
  pos = np.asarray(positions, dtype=np.float64)
  out = pos.copy()
  lengths = skel.bone_lengths
  for j in range(1, 24):
    p = skel.parents[j]
    out[..., j, :] = out[..., p, :] + lengths[j] * _unit(pos[..., j, :] - pos[..., p, :])
  return out


def resample(x: np.ndarray, fps_in: float, fps_out: float = FPS) -> np.ndarray:
  """Resamples a (T, ...) signal with cubic (Catmull-Rom) interpolation; keeps the first frame's time."""
  t_in = x.shape[0]
  duration = (t_in - 1) / fps_in
  t_out = int(np.floor(duration * fps_out + 1e-9)) + 1
  s = np.arange(t_out) * (fps_in / fps_out)
  i = np.clip(np.floor(s).astype(np.int64), 0, t_in - 1)
  f = (s - i).reshape((-1,) + (1,) * (x.ndim - 1))

  # Ghost samples beyond both ends extrapolate linearly, so lines stay lines up to the edges.
  xp = np.concatenate([2 * x[:1] - x[1:2], x, 2 * x[-1:] - x[-2:-1], 2 * x[-1:] - x[-2:-1]], axis=0)

  def at(k):
    return xp[np.clip(k, -1, t_in + 1) + 1]
  p0, p1, p2, p3 = at(i - 1), at(i), at(i + 1), at(i + 2)
  return 0.5 * ((2 * p1) + (-p0 + p2) * f + (2 * p0 - 5 * p1 + 4 * p2 - p3) * f ** 2 +
                (-p0 + 3 * p1 - 3 * p2 + p3) * f ** 3)


def find_spikes(x: np.ndarray, threshold: float, max_width: int = 2, ratio: float = 3.0) -> np.ndarray:
  """Flags (T, N) samples of a (T, N, 3) trajectory that are short excursions: out and back.

  A run of w <= max_width frames is a spike when it leaves the straight line between the frames around it
  by more than `threshold` and by more than `ratio` times the distance between those two frames. Fast but
  real motion (a tango step covers 1 m in 4 frames) moves the surrounding frames apart and is kept; a
  glitch returns to where it left.
  """
  t_len = x.shape[0]
  bad = np.zeros(x.shape[:2], dtype=bool)
  for w in range(1, max_width + 1):
    if t_len < w + 2:
      break
    a = x[:t_len - w - 1]
    b = x[w + 1:]
    span = np.linalg.norm(b - a, axis=-1)
    devs = [np.linalg.norm(x[k:t_len - w - 1 + k] - (a + (k / (w + 1)) * (b - a)), axis=-1)
            for k in range(1, w + 1)]
    # Every frame of the run must be off the line (else a shorter run explains it).
    dev = np.min(devs, axis=0)
    hit = (dev > threshold) & (dev > ratio * span)
    for k in range(1, w + 1):
      bad[k:t_len - w - 1 + k] |= hit
  return bad


def remove_spikes(x: np.ndarray, threshold: float) -> tuple[np.ndarray, int]:
  """Replaces the samples `find_spikes` flags by linear interpolation from the same point's good frames.
  Returns the cleaned copy and the number of (frame, point) samples replaced."""
  bad = find_spikes(x, threshold)
  out = x.copy()
  t = np.arange(x.shape[0])
  for n in np.nonzero(bad.any(0))[0]:
    good = ~bad[:, n]
    for c in range(3):
      out[~good, n, c] = np.interp(t[~good], t[good], x[good, n, c])
  return out, int(bad.sum())


def floor_height(positions: np.ndarray, window_s: float = 2.0, fps: float = FPS) -> np.ndarray:
  """Slowly varying floor estimate (T,): running minimum of the lowest foot joint, then smoothed.

  Dancers here keep at least one foot on the floor nearly all the time, so the lowest foot joint over a
  2-second window is the floor; smoothing the running minimum removes the slow height drift of a capture
  without flattening short jumps (a jump shorter than the window does not lower the minimum).
  """
  from scipy.ndimage import gaussian_filter1d, minimum_filter1d
  low = positions[:, FOOT_JOINTS, 1].min(axis=1)
  w = max(1, int(round(window_s * fps)))
  floor = minimum_filter1d(low, size=w, mode="nearest")
  return gaussian_filter1d(floor, sigma=w / 2, mode="nearest")


def put_on_floor(positions: np.ndarray, fps: float = FPS) -> np.ndarray:
  """Shifts every frame vertically so the (smoothed) lowest foot joint sits at y = 0."""
  return positions - floor_height(positions, fps=fps)[:, None, None] * np.array([0.0, 1.0, 0.0])
