"""Pose representation (docs/model.md section 7): round trip, invariances, bone projection, rotations."""
import numpy as np
import pytest

from training.data import representation as rep
from training.data import rotations as rot
from training.data import skeleton as sk
from training.data import sources
from training.data.skeleton import J

SKEL = sk.load_skeleton()


def _dance(seed=0, t=900):
  """A synthetic dance: rest pose with moving limbs, walking a curved path and turning."""
  rng = np.random.default_rng(seed)
  rest = SKEL.rest_positions()
  n = np.arange(t)
  wobble = 0.15 * np.sin(n[:, None, None] / 7.0 + rng.uniform(0, 6, (1, 24, 3)))
  pos = rest[None] + wobble
  theta = 0.8 * np.sin(n / 90.0) + n * 0.01
  pos = np.einsum("tij,tnj->tni", rep.rot_y(theta), pos)
  pos[:, :, 0] += np.cumsum(0.02 * np.cos(n / 50.0))[:, None]
  pos[:, :, 2] += np.cumsum(0.02 * np.sin(n / 40.0))[:, None]
  pos[:, :, 1] += 0.95
  return sk.project_bone_lengths(pos, SKEL)


def test_rest_pose_faces_plus_z():
  # SMPL's rest hips and shoulders are not exactly parallel to X: the rest pose faces +Z within 1.2 deg.
  yaw0 = rep.facing_yaw(SKEL.rest_positions())
  assert abs(yaw0) < 0.02
  turned = SKEL.rest_positions() @ rep.rot_y(np.array(0.5)).T
  assert rep.facing_yaw(turned) == pytest.approx(yaw0 + 0.5, abs=1e-12)


def test_round_trip_whole_dance_float32():
  p = _dance().astype(np.float32)
  upper, lower = rep.encode(p)
  assert upper.shape == (900, 45) and lower.shape == (900, 31)
  theta = rep.facing_yaw(p)
  q = rep.decode(upper.astype(np.float32), lower.astype(np.float32), theta[0], p[0, 0, [0, 2]])
  assert np.abs(q - p).max() < 1e-4


def test_default_start_is_origin_facing_plus_z():
  upper, lower = rep.encode(_dance())
  q = rep.decode(upper, lower)
  assert np.abs(q[0, 0, [0, 2]]).max() < 1e-12
  assert rep.facing_yaw(q[0]) == pytest.approx(0.0, abs=1e-9)


def test_representation_is_invariant_to_world_yaw_and_position():
  p = _dance(1, 200)
  moved = np.einsum("ij,tnj->tni", rep.rot_y(np.array(2.0)), p) + np.array([3.0, 0.0, -1.0])
  a, b = rep.encode(p), rep.encode(moved)
  np.testing.assert_allclose(a[0], b[0], atol=1e-9)
  np.testing.assert_allclose(a[1], b[1], atol=1e-9)


def test_lower_layout_and_left_is_plus_x():
  upper, lower = rep.encode(SKEL.rest_positions()[None] + [0.0, 0.9, 0.0])
  assert lower[0, 0:3] == pytest.approx([0.0, 0.9, 0.0])              # pelvis row (0, h, 0)
  assert lower[0, rep.ROOT_HEIGHT] == pytest.approx(0.9)
  assert lower[0, 3] > 0 and lower[0, 6] < 0                          # left hip +x, right hip -x
  i = sk.UPPER_JOINTS.index(J["left_wrist"])
  assert upper[0, 3 * i] > 0.5


def test_heading_wraps():
  t = 400
  theta = np.linspace(0, 6 * np.pi, t)                                # three full turns
  p = np.einsum("tij,nj->tni", rep.rot_y(theta), SKEL.rest_positions())
  _, lower = rep.encode(p)
  assert np.abs(lower[1:, rep.ROOT_YAW_RATE] - theta[1]).max() < 1e-9
  q = rep.decode(*rep.encode(p))    # starts facing +Z exactly (yaw 0), then turns with theta
  np.testing.assert_allclose(rep.facing_yaw(q), rep.wrap_angle(theta), atol=1e-9)
  np.testing.assert_allclose(rep.facing_yaw(p), rep.wrap_angle(theta + rep.facing_yaw(p[0])), atol=1e-9)


def test_bone_projection():
  p = _dance(2, 50) + np.random.default_rng(0).normal(0, 0.02, (50, 24, 3))
  q = sk.project_bone_lengths(p, SKEL)
  lengths = np.linalg.norm(q[:, 1:] - q[:, SKEL.parents[1:]], axis=-1)
  np.testing.assert_allclose(lengths, np.broadcast_to(SKEL.bone_lengths[1:], lengths.shape), atol=1e-12)
  np.testing.assert_allclose(q[:, 0], p[:, 0])


def test_rotations_reproduce_positions():
  p = _dance(3, 120)
  q = rot.local_rotations(p, SKEL)
  np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
  # Every single-child joint's global rotation turns its child's rest offset onto the posed bone.
  g = rot.global_rotations(p, SKEL)
  for j, c in rot.PRIMARY_CHILD.items():
    d = rot.quat_rotate(g[:, j], np.broadcast_to(SKEL.offsets[c], (len(p), 3)))
    posed = p[:, c] - p[:, j]
    cos = (d * posed).sum(-1) / np.linalg.norm(d, axis=-1) / np.linalg.norm(posed, axis=-1)
    assert cos.min() > 1 - 1e-12, (j, c)
  # Local rotations compose back to the globals.
  f = rot.forward_kinematics(q, p[:, 0], SKEL)
  assert np.isfinite(f).all()
  rest_q = rot.local_rotations(SKEL.rest_positions()[None], SKEL)
  np.testing.assert_allclose(rest_q[0], np.tile([1.0, 0, 0, 0], (24, 1)), atol=1e-12)


def test_shortest_arc_opposite_directions():
  q = rot.shortest_arc(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),
                       np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]]))
  v = rot.quat_rotate(q, np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
  np.testing.assert_allclose(v, [[0, -1, 0], [-1, 0, 0]], atol=1e-12)


@pytest.mark.skipif(not (sk.SHARED_DATA / "tang2018").exists(), reason="../shared/data not present")
def test_round_trip_real_dance():
  p = sources.convert_tang(sk.SHARED_DATA / "tang2018" / "DANCE_R_4", SKEL).positions
  upper, lower = rep.encode(p)
  q = rep.decode(upper.astype(np.float32), lower.astype(np.float32), rep.facing_yaw(p)[0],
                 p[0, 0, [0, 2]])
  assert np.abs(q - p).max() < 1e-4


@pytest.mark.skipif(not (sk.SHARED_DATA / "tang2018").exists(), reason="../shared/data not present")
def test_rotations_fk_exact_on_converted_data():
  # Converted data has a rigid pelvis and upper trunk, so FK of the rotations reproduces every joint.
  p = sources.convert_tang(sk.SHARED_DATA / "tang2018" / "DANCE_C_2", SKEL).positions.astype(np.float64)
  f = rot.forward_kinematics(rot.local_rotations(p, SKEL), p[:, 0], SKEL)
  assert np.abs(f - p).max() < 1e-6
