"""Data conversion checks: bone lengths, fps, left/right, floor, AIST++ loader, BVH reader, split."""
import json
import pathlib
import pickle

import numpy as np
import pytest

from training.data import aistpp, bvh, prepare, sources
from training.data import skeleton as sk
from training.data.skeleton import J

DATA = sk.SHARED_DATA
SKEL = sk.load_skeleton()
needs_data = pytest.mark.skipif(not (DATA / "tang2018").exists(), reason="../shared/data not present")


def _forward(p):
  across = p[:, J["left_hip"]] - p[:, J["right_hip"]]
  f = np.cross(across, [0.0, 1.0, 0.0])
  return f / np.linalg.norm(f, axis=-1, keepdims=True)


def _check_motion(m: sources.Motion, foot: str = "left"):
  p = m.positions.astype(np.float64)
  assert m.positions.dtype == np.float32 and p.shape[1:] == (24, 3)
  assert m.fps == 30
  bones = np.linalg.norm(p[:, 1:] - p[:, SKEL.parents[1:]], axis=-1)
  np.testing.assert_allclose(bones, np.broadcast_to(SKEL.bone_lengths[1:], bones.shape), atol=2e-6)
  # Left is +x in the body's facing frame: the left hip lies on the left of the forward direction.
  fwd = _forward(p)
  left_axis = np.cross([0.0, 1.0, 0.0], fwd)
  side = ((p[:, J["left_shoulder"]] - p[:, J["right_shoulder"]]) * left_axis).sum(-1)
  assert (side > 0).mean() > 0.95
  # Feet point forward (toe ahead of ankle) and knees bend forward, most of the time.
  toe = ((p[:, J[f"{foot}_foot"]] - p[:, J[f"{foot}_ankle"]]) * fwd).sum(-1)
  assert (toe > 0).mean() > 0.9
  # Feet on the floor: the lowest foot joint sits near y = 0, the head above 1.3 m when upright.
  low = p[:, sk.FOOT_JOINTS, 1].min(1)
  assert abs(np.median(low)) < 0.06 and low.min() > -0.05
  assert np.median(p[:, J["head"], 1]) > 1.3
  return p


@needs_data
def test_tang_conversion_and_timing():
  m = sources.convert_tang(DATA / "tang2018" / "DANCE_W_3", SKEL)
  p = _check_motion(m)
  src = np.load(DATA / "tang2018" / "DANCE_W_3" / "motion.npz")["skeletons"]
  span = 1699 - 52                                                   # config end - start (25 fps)
  fps_in = 25 * src.shape[0] / span                                  # frames spread over the span
  assert p.shape[0] == int((src.shape[0] - 1) / fps_in * 30 + 1e-9) + 1
  assert m.audio_offset_s == pytest.approx(52 / 25)                  # config.json start_position / 25
  assert m.style == "waltz" and m.audio_path.endswith("audio.ogg")
  # No height drift after floor alignment: pelvis height at the start and end of the take agree.
  h = p[:, 0, 1]
  assert abs(np.median(h[:300]) - np.median(h[-300:])) < 0.05


@needs_data
@pytest.mark.parametrize("path,mapping,scale,style", [
    ("mocap/cmu_salsa/60_01_scaled.bvh", sources.CMU_MAP, 1.0, "salsa"),
    ("mocap/perfume/aachan.bvh", sources.PERFUME_MAP, 0.01, "pop")])
def test_bvh_sources(path, mapping, scale, style):
  m = sources.convert_bvh(DATA / path, mapping, scale, style, "x", SKEL)
  p = _check_motion(m)
  step = np.linalg.norm(np.diff(p[:, 0], axis=0), axis=-1)
  assert step.max() < 0.2     # no teleporting root (Perfume's leading rest frame is dropped)


def test_bvh_reader_forward_kinematics(tmp_path):
  text = """HIERARCHY
ROOT hip
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT knee
  {
    OFFSET 0 -1 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -2 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.025
1 2 3 0 0 0 0 0 0
0 0 0 90 0 0 0 90 0
"""
  f = tmp_path / "t.bvh"
  f.write_text(text)
  b = bvh.read_bvh(f)
  assert b.names == ["hip", "knee", "knee_end"] and b.fps == pytest.approx(40)
  p = b.global_positions()
  np.testing.assert_allclose(p[0], [[1, 2, 3], [1, 1, 3], [1, -1, 3]], atol=1e-12)
  # Frame 1: hip rotated 90 deg about Z maps (0,-1,0) to (1,0,0); knee adds 90 deg about X, so its
  # child offset (0,-2,0) -> Rz(90) Rx(90) (0,-2,0) = Rz(90) (0,0,-2) = (0,0,-2).
  np.testing.assert_allclose(p[1], [[0, 0, 0], [1, 0, 0], [1, 0, -2]], atol=1e-12)


def test_aistpp_loader(tmp_path):
  t = 8
  poses = np.zeros((t, 72))
  poses[:, 3 * J["left_knee"]] = np.pi / 2          # left knee: 90 degrees about X
  trans = np.stack([np.arange(t) * 0.2, np.full(t, 1.9), np.zeros(t)], -1)   # scaled space
  (tmp_path / "motions").mkdir()
  with open(tmp_path / "motions" / "gBR_sBM_cAll_d04_mBR0_ch01.pkl", "wb") as f:
    pickle.dump({"smpl_poses": poses, "smpl_trans": trans, "smpl_scaling": np.array([2.0])}, f)
  with open(tmp_path / "motions" / "gPO_sBM_cAll_d10_mPO1_ch02.pkl", "wb") as f:
    pickle.dump({"smpl_poses": poses, "smpl_trans": trans, "smpl_scaling": 1.0}, f)
  out = list(aistpp.load_aistpp(tmp_path, SKEL, ignore={"gPO_sBM_cAll_d10_mPO1_ch02"}))
  assert [i for i, _ in out] == ["aist_gBR_sBM_cAll_d04_mBR0_ch01"]
  m = out[0][1]
  assert m.style == "break" and m.fps == 30 and m.audio_path.endswith("wavs/mBR0.wav")
  p = m.positions.astype(np.float64)
  assert p.shape == (4, 24, 3)                                # 60 -> 30 fps
  np.testing.assert_allclose(p[:, 0, 0], trans[::2, 0] / 2.0, atol=1e-6)   # trans / scaling
  bones = np.linalg.norm(p[:, 1:] - p[:, SKEL.parents[1:]], axis=-1)
  np.testing.assert_allclose(bones, np.broadcast_to(SKEL.bone_lengths[1:], bones.shape), atol=1e-6)
  rest = SKEL.rest_positions()
  rel = p[0] - p[0, 0]
  np.testing.assert_allclose(rel[J["right_ankle"]], rest[J["right_ankle"]], atol=1e-6)  # untouched leg
  c, s = 0.0, 1.0
  o = SKEL.offsets[J["left_ankle"]]
  expect = rest[J["left_knee"]] + np.array([o[0], c * o[1] - s * o[2], s * o[1] + c * o[2]])
  np.testing.assert_allclose(rel[J["left_ankle"]], expect, atol=1e-6)
  assert p[:, sk.FOOT_JOINTS, 1].min() == pytest.approx(0.0, abs=1e-6)


def test_spike_removal_keeps_fast_motion():
  t = np.arange(100, dtype=np.float64)
  x = np.zeros((100, 2, 3))
  x[:, 0, 0] = 0.3 * t                      # fast but smooth: 9 m/s
  x[:, 1, 1] = np.sin(t / 20)
  x[40, 1, 1] += 0.3                        # one-frame glitch
  x[60:62, 1, 2] += 0.6                     # two-frame glitch
  out, n = sk.remove_spikes(x, threshold=0.05)
  assert n == 3
  np.testing.assert_allclose(out[:, 0], x[:, 0])
  assert abs(out[40, 1, 1] - np.sin(2.0)) < 0.02 and abs(out[60, 1, 2]) < 1e-9


def test_resample_preserves_duration_and_lines():
  x = np.linspace(0, 1, 26)[:, None]        # 1 s at 25 fps
  y = sk.resample(x, 25, 30)
  assert y.shape[0] == 31
  np.testing.assert_allclose(y[:, 0], np.linspace(0, 1, 31), atol=1e-12)


def test_split_file():
  split = json.loads((prepare.REPO / "training" / "split.json").read_text())
  val, train = set(split["validation"]), set(split["train"])
  assert not val & train
  styles = {v.split("_")[2] for v in val if v.startswith("tang_")}
  assert styles == {"C", "R", "T", "W"}
  tang_val_songs = {v.rsplit("_", 1)[0] if v.endswith(("_a", "_b")) else v for v in val}
  assert 6 <= len(tang_val_songs) <= 10                   # ~20 % of the 38 songs
  assert not any(s.startswith(("cmu_", "perfume_")) for s in val)


@needs_data
def test_every_source_take_converts_cleanly():
  n = 0
  for ids, thunk in prepare.jobs(DATA, SKEL):
    for motion_id, m in zip(ids, thunk()):
      p = _check_motion(m)
      assert np.isfinite(p).all(), motion_id
      assert np.linalg.norm(np.diff(p[:, 0], axis=0), axis=-1).max() < 0.25, motion_id   # < 7.5 m/s
      n += 1
  assert n == 70


def test_mirror_swaps_sides_turns_the_other_way_and_keeps_the_skeleton():
  from training.data import representation as rep
  skel = sk.load_skeleton()
  rest = skel.rest_positions()
  t = np.arange(60) / 30.0
  # A body walking forward along +Z while turning left (yaw increasing) and raising its left hand.
  yaw = 0.5 * t
  pos = np.einsum("tij,nj->tni", rep.rot_y(yaw), rest)
  pos[:, :, 2] += 0.4 * t[:, None]
  pos[:, :, 1] += 1.0
  pos[:, J["left_wrist"], 1] += 0.2 * t
  pos = sk.project_bone_lengths(pos, skel)
  m = sk.mirror_positions(pos, skel)
  # Canonical bone lengths kept (the canonical left and right bones differ by ~1 cm).
  d = np.linalg.norm(m[:, 1:] - m[:, skel.parents[1:]], axis=-1)
  assert np.allclose(d, skel.bone_lengths[1:][None], atol=1e-9)
  # The raised hand is now the right one, on the mirrored side.
  assert m[-1, J["right_wrist"], 1] > m[-1, J["left_wrist"], 1] + 0.1
  assert np.isclose(m[-1, J["right_wrist"], 0], -pos[-1, J["left_wrist"], 0], atol=0.02)
  # It turns right as much as the original turned left, and still walks forward (up to the facing's
  # small change when the hips and shoulders go back on the canonical lengths).
  _, low = rep.encode(pos)
  _, low_m = rep.encode(m)
  assert np.allclose(low_m[1:, rep.ROOT_YAW_RATE], -low[1:, rep.ROOT_YAW_RATE], atol=1e-4)
  assert np.allclose(low_m[:, rep.ROOT_VZ], low[:, rep.ROOT_VZ], atol=1e-4)
  assert np.allclose(low_m[:, rep.ROOT_VX], -low[:, rep.ROOT_VX], atol=1e-4)
  assert np.abs(low[1:, rep.ROOT_YAW_RATE]).min() > 0.01 and np.abs(low[1:, rep.ROOT_VX]).max() > 0.002
  # Twice is the identity on canonical-skeleton motion.
  assert np.allclose(sk.mirror_positions(m, skel), pos, atol=1e-9)


@needs_data
def test_tang_lady_reading_is_the_mirror_of_the_captured_one():
  # docs/data.md "Left vs right": the lady's reading (3-11 left, the capture mirrored) passes every check the
  # captured one does (sides, toes ahead, floor), puts the hold's extended arm on the right, and is the
  # captured dance reflected left-right.
  cap = sources.convert_tang(DATA / "tang2018" / "DANCE_W_3", SKEL)
  lady = sources.convert_tang(DATA / "tang2018" / "DANCE_W_3", SKEL, sides="lady")
  p = _check_motion(lady, foot="right")  # the captured reading's left foot (98 % toe ahead; its right: 89 %)
  assert lady.notes["tang_sides"] == "lady" and cap.notes["tang_sides"] == "captured"
  fwd = _forward(p)
  left_axis = np.cross([0.0, 1.0, 0.0], fwd)
  def out(wrist, shoulder):
    return np.median(np.abs(((p[:, J[wrist]] - p[:, J[shoulder]]) * left_axis).sum(-1)))
  assert out("right_wrist", "right_shoulder") > out("left_wrist", "left_shoulder") + 0.1
  mirrored = sk.mirror_positions(cap.positions)
  assert np.median(np.abs(mirrored - lady.positions)) < 0.01
  with pytest.raises(ValueError):
    sources.convert_tang(DATA / "tang2018" / "DANCE_W_3", SKEL, sides="man")


def test_prepare_rewrites_a_cache_of_the_other_reading(tmp_path):
  path = tmp_path / "tang_x.npz"
  m = sources.Motion(np.zeros((4, 24, 3), np.float32), 30.0, "waltz", "tang2018", notes={"tang_sides": "captured"})
  prepare._save(path, m)
  assert prepare._fresh(path) and prepare._fresh(path, "captured") and not prepare._fresh(path, "lady")
