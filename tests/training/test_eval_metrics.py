"""Metric sanity: each metric separates what it should, on synthetic dances with known answers."""
import json
import shutil
import subprocess

import numpy as np
import pytest

from training.data import skeleton as sk
from training.data.skeleton import J
from training.eval import evaluate, features, metrics, tempo

SKEL = sk.load_skeleton()
FPS = 30.0


def _dance(seconds=30.0, period=1.0, seed=0, amp=0.25, sway=0.3):
  """Rest pose on the floor; arms and legs swing with the given period (speed minima twice a period)."""
  rng = np.random.default_rng(seed)
  t = np.arange(int(seconds * FPS)) / FPS
  rest = SKEL.rest_positions()
  rest[:, 1] -= rest[list(sk.FOOT_JOINTS), 1].min()
  pos = np.repeat(rest[None], len(t), axis=0)
  phase = rng.uniform(0, 2 * np.pi)
  for j in (J["left_wrist"], J["right_wrist"], J["left_hand"], J["right_hand"], J["left_elbow"],
            J["right_elbow"], J["head"]):
    pos[:, j, 2] += amp * np.sin(2 * np.pi * t / period + phase + rng.uniform(0, 0.3))
    pos[:, j, 1] += 0.5 * amp * np.sin(4 * np.pi * t / period + phase)
  pos[:, :, 0] += sway * np.sin(2 * np.pi * t / (4 * period) + phase)[:, None]
  return pos


def test_frechet_distance_basics():
  rng = np.random.default_rng(0)
  a = rng.normal(size=(400, 5))
  assert metrics.frechet_distance(a, a) == pytest.approx(0.0, abs=1e-6)
  assert metrics.frechet_distance(a, a + 2.0) == pytest.approx(20.0, rel=1e-6)
  # the split: a shift is all mean term, a rescale all covariance term, and the parts sum to the distance
  assert metrics.frechet_parts(a, a + 2.0) == pytest.approx((20.0, 0.0), abs=1e-6)
  b = a * 2.0
  m, c = metrics.frechet_parts(a, b)
  assert m == pytest.approx(((a.mean(0) - b.mean(0)) ** 2).sum())
  assert m + c == pytest.approx(metrics.frechet_distance(a, b))
  assert c > 4.0  # 5 dimensions of std ~1 against ~2: (2 - 1)^2 each


def test_frozen_pose_scores_worse_than_real_on_fid():
  real = [evaluate.Dance(f"r{i}", _dance(seed=i, period=0.8 + 0.05 * i)) for i in range(8)]
  val = [evaluate.Dance(f"v{i}", _dance(seed=100 + i, period=0.8 + 0.05 * i)) for i in range(4)]
  ev = evaluate.Evaluator(real, val)
  frozen = [evaluate.Dance(d.name, np.repeat(d.positions[:1], len(d.positions), 0)) for d in val]
  r, f = ev.evaluate(val), ev.evaluate(frozen)
  assert f["fid_k"] > 5 * r["fid_k"] and f["fid_g"] > r["fid_g"]
  assert f["div_k"] == pytest.approx(0.0) and r["div_k"] > 0.5
  assert f["jitter"] == 0.0 and r["bone_err_mm"] < 50


def test_bas_of_motion_made_from_beats_is_high():
  ibi = 0.6
  beats = np.arange(0.3, 29.0, ibi)
  t = np.arange(int(30 * FPS)) / FPS
  pos = np.repeat(SKEL.rest_positions()[None], len(t), axis=0)
  # Hands move back and forth, stopping exactly on every beat: speed minima = beats.
  x = 0.3 * np.cos(np.pi * (t - 0.3) / ibi)
  pos[:, J["left_wrist"], 2] += x
  pos[:, J["right_wrist"], 2] += x
  mb = metrics.motion_beats(pos, FPS)
  bas = metrics.beat_align_score(beats, mb)
  chance = metrics.beat_align_chance(beats, mb)
  assert bas > 0.9 and chance < 0.6
  # The same motion against beats half a beat away scores low.
  assert metrics.beat_align_score(beats + ibi / 2, mb) < 0.2


def test_dominant_period_and_time_stretch():
  pos = _dance(period=2.4, seconds=40, sway=0.0)
  # A swing of period 2.4 s stops twice per period: the speed's period is 1.2 s.
  assert tempo.dominant_period(pos) == pytest.approx(1.2, rel=0.03)
  fast = tempo.time_stretch_motion(pos, 1.15)
  assert tempo.dominant_period(fast, around_s=1.2) == pytest.approx(1.2 / 1.15, rel=0.03)
  assert tempo.fit_ratio([0.85, 1.15], [1.2 / 0.85, 1.2 / 1.15], 1.2) == pytest.approx(1.0)
  assert tempo.fit_ratio([0.85, 1.15], [1.2, 1.2], 1.2) == pytest.approx(0.0)


def test_perfect_follower_ratio():
  a = _dance(period=2.0, seconds=40, sway=0.0)
  # Draws that share one period: the ideal follower scores 1.
  assert tempo.perfect_follower_ratio(a, [a, a]) == pytest.approx(1.0, abs=0.05)
  # The draw for 0.85x 10 % faster than the base, the one for 1.15x 10 % slower: the spread alone pulls the
  # statistic down to 1 + (x1 log(1/1.1) + x2 log(1.1)) / (x1^2 + x2^2), x_f = log(1/f).
  fast, slow = _dance(period=2.0 / 1.1, seconds=40, sway=0.0), _dance(period=2.2, seconds=40, sway=0.0)
  x = np.log(1 / np.array([0.85, 1.15]))
  expect = 1 + (x[0] * np.log(1 / 1.1) + x[1] * np.log(1.1)) / (x ** 2).sum()
  assert expect < 0.5
  assert tempo.perfect_follower_ratio(a, [fast, slow]) == pytest.approx(expect, abs=0.1)


def test_section_follower_ratios():
  # A dance with one steady period: every section is the same draw, the ideal follower scores 1.
  steady = _dance(period=2.0, seconds=70, sway=0.0)
  r = tempo.section_follower_ratios(steady, window_s=30, hop_s=10)
  assert len(r) == 5 and np.allclose(r, 1.0, atol=0.05)
  # Sections alternating between two periods 10 % apart: each triple is off 1 (by the formula of
  # test_perfect_follower_ratio: 1.34 with base A, 0.66 with base B), the errors cancel in the mean.
  a, b = _dance(period=2.0, seconds=30, sway=0.0), _dance(period=2.2, seconds=30, sway=0.0)
  r = tempo.section_follower_ratios(np.concatenate([a, b, a, b]), window_s=30, hop_s=30)
  assert len(r) == 4 and np.allclose(sorted(r), [0.66, 0.66, 1.34, 1.34], atol=0.1)
  # Fewer than three sections: nothing to report.
  assert tempo.section_follower_ratios(steady[:45 * 30], window_s=30, hop_s=10) == []


def test_bootstrap_se_of_the_mean_ratio():
    from training.eval.engine_tempo import bootstrap_se
    assert bootstrap_se([0.7]) is None
    assert bootstrap_se([0.5] * 10) == 0.0
    v = np.random.default_rng(3).normal(0.4, 0.8, size=400)
    se = bootstrap_se(v)
    assert abs(se - 0.8 / np.sqrt(400)) < 0.01
    assert bootstrap_se(v) == se  # repeatable


@pytest.mark.skipif(shutil.which("sox") is None, reason="sox not installed")
def test_tempo_following_with_a_generator(tmp_path):
  wav = tmp_path / "click.wav"
  subprocess.run(["sox", "-n", "-r", "24000", "-c", "1", str(wav), "synth", "20", "sine", "440"],
                 check=True, capture_output=True)
  base = _dance(period=2.0, seconds=40, sway=0.0)
  seen = []

  def follower(audio_path):
    seen.append(audio_path)
    f = float(audio_path.rsplit("_x", 1)[1][:-4]) if "_x" in audio_path else 1.0
    return tempo.time_stretch_motion(base, f)

  r = tempo.tempo_following(follower, wav, tmp_path)
  assert r["ratio"] == pytest.approx(1.0, abs=0.05) and len(seen) == 3
  r0 = tempo.tempo_following(lambda a: base, wav, tmp_path)
  assert abs(r0["ratio"]) < 0.05


def test_foot_skating_and_jitter():
  planted = _dance(seconds=10)
  planted[:, :, 0] = planted[:1, :, 0]          # no travel: feet stay put
  sliding = planted.copy()
  sliding[:, :, 0] += np.arange(len(sliding))[:, None] * (0.5 / FPS)   # whole body slides at 0.5 m/s
  assert metrics.foot_skating(planted) < 0.01
  assert metrics.foot_skating(sliding) == pytest.approx(0.5, rel=0.01)
  noisy = planted + np.random.default_rng(0).normal(0, 0.01, planted.shape)
  assert metrics.jitter(noisy) > 10 * metrics.jitter(planted)


def test_turn_rate_and_spin_flag():
  from training.data.representation import rot_y
  still = _dance(seconds=10)
  centre = still[:, :1].copy()
  centre[..., 1] = 0.0
  yaw = np.arange(len(still)) * (4.0 / FPS)      # turning at 4 rad/s about the pelvis
  spinning = np.einsum("tij,tnj->tni", rot_y(yaw), still - centre) + centre
  assert metrics.turn_rate(still) < 0.05
  assert metrics.turn_rate(spinning) == pytest.approx(4.0, rel=0.02)
  assert metrics.turn_rate(spinning[::-1]) == pytest.approx(4.0, rel=0.02)   # either direction
  rows = evaluate.segment_table([evaluate.Dance("a", still), evaluate.Dance("b", spinning)],
                                beats_of=lambda d: np.zeros(0))["rows"]
  assert [r["spin"] for r in rows] == [0.0, 1.0]


def test_bone_length_error_and_pfc():
  pos = _dance(seconds=10)
  stretched = pos.copy()
  stretched[:, J["left_wrist"]] += [0.05, 0.0, 0.0]
  proj = sk.project_bone_lengths(pos, SKEL)
  assert metrics.bone_length_error(proj, SKEL.parents, SKEL.bone_lengths)["bone_err_max_mm"] < 1e-6
  assert metrics.bone_length_error(sk.project_bone_lengths(stretched, SKEL), SKEL.parents,
                                   SKEL.bone_lengths)["bone_err_max_mm"] < 1e-6
  # Feet moving while the pelvis accelerates sideways scores worse than feet planted.
  t = np.arange(len(pos)) / FPS
  glide = pos.copy()
  glide[:, :, 0] += (0.2 * np.sin(2 * np.pi * t))[:, None]
  planted = glide.copy()
  for j in (J["left_ankle"], J["left_foot"], J["right_ankle"], J["right_foot"]):
    planted[:, j] = glide[:1, j]
  assert metrics.pfc(glide) > 3 * metrics.pfc(planted)


def test_segments_and_features_shapes():
  pos = _dance(seconds=25)
  segs = features.segments(pos)
  assert [len(s) for s in segs] == [300, 300]
  assert features.kinetic_features(segs[0]).shape == (72,)
  g = features.geometric_features(segs[0])
  assert g.shape == (len(features.GEOMETRIC_NAMES),) and ((g >= 0) & (g <= 1)).all()


def test_load_dance_json(tmp_path):
  pos = _dance(seconds=2)
  f = tmp_path / "d.json"
  f.write_text(json.dumps({"format": "dance-motion/v1", "fps": 30, "units": "m", "up_axis": "y",
                           "joint_names": list(sk.JOINT_NAMES), "positions": pos.tolist(),
                           "audio_offset_s": 1.5, "audio_path": "song.ogg"}))
  d = evaluate.load_dance(f)
  np.testing.assert_allclose(d.positions, pos)
  assert d.audio_offset_s == 1.5 and d.audio_path == "song.ogg"
  f.write_text(json.dumps({"format": "other"}))
  with pytest.raises(ValueError):
    evaluate.load_dance(f)


def test_beat_phases_and_lock():
  from training.eval.data_checks import beat_phases, phase_drift
  beats = np.arange(0.0, 60.0, 0.5)
  events = beats[:-1] + 0.125                          # always a quarter beat late
  ph = beat_phases(events, beats)
  np.testing.assert_allclose(ph, 0.25)
  assert abs(phase_drift(events, beats)) < 1e-9
  drifting = beats[:-1] * 1.01                         # 1 % fast against the beats: phase walks
  assert phase_drift(drifting, beats) > 0.5


def test_beat_lock_separates_locked_from_unlocked():
  ibi = 0.6
  t = np.arange(int(60 * FPS)) / FPS
  pos = np.repeat(SKEL.rest_positions()[None], len(t), axis=0)
  pos[:, J["left_wrist"], 2] += 0.3 * np.cos(np.pi * t / ibi)
  d = evaluate.Dance("x", pos)
  locked = evaluate.beat_lock(d, np.arange(0.0, 60.0, ibi))
  other = evaluate.beat_lock(d, np.arange(0.0, 60.0, 0.71))
  assert locked["lock_r"] > 0.9 and other["lock_r"] < 3 * other["lock_chance"]
  assert locked["period_dev"] < 0.02


def test_tracker_level_errors_fold_octaves_only():
    from training.experiments.tracker_levels import level_errors, octave_flips, octave_mismatches, window_tempi
    base = [100.0, 120.0, 120.0, 120.0]
    # 0.85x: exact following, an octave below (the clock folds it), and a 3/2 switch.
    stretched = [90.0, 102.0, 51.0, 153.0]
    e = level_errors(base, stretched, 0.85)
    assert len(e) == 3 and abs(e[0]) < 1e-9 and abs(e[1]) < 1e-9
    assert abs(e[2] - (np.log2(1.5) - 1.0)) < 1e-9  # 3/2 = 3/4 up to an octave: off-level
    assert octave_flips([90.0, 102.0, 51.0, 102.0, 104.0]) == 2
    # The octave below is a mismatch, and so is 3/2 (log2 0.58: nearer the octave above); exact is not.
    assert octave_mismatches(base, stretched, 0.85) == 2
    assert octave_mismatches(base, [90.0, 102.0, 136.0, 102.0], 0.85) == 0  # 4/3: off-level, same octave
    # Window medians in music time: a version played twice as fast covers window k in half the frames.
    tempo = np.concatenate([np.full(150, 80.0), np.full(150, 90.0)])
    assert window_tempi(tempo, 2.0, 2) == [80.0, 90.0]


def test_bar_seconds_folds_like_the_clock():
    from training.experiments.period_in_bars import bar_seconds
    # A waltz tracked at the eighth-note level (174 BPM) folds to 87 BPM: a 3-beat bar of 2.07 s.
    assert abs(bar_seconds(174.0, 86.03, "waltz") - 3 * 60 / 87.0) < 1e-9
    assert abs(bar_seconds(87.0, 86.03, "waltz") - 3 * 60 / 87.0) < 1e-9
    # A cha-cha at 125 BPM: 4 beats.
    assert abs(bar_seconds(125.0, 125.05, "cha-cha") - 4 * 60 / 125.0) < 1e-9


def test_dance_period_beats_measures_each_styles_period_on_the_warped_timeline(tmp_path, monkeypatch):
  # Two waltzes whose speed repeats every 3 beats of the style's reference (R = 90: a beat is 20 warped
  # frames, 3 beats 2 s), a cha-cha at 2 beats of 120 BPM (1 s), and a motion-only dance (no music): left out.
  from training.common import clips as td
  refs = {"waltz": 90.0, "cha-cha": 120.0, "salsa": 105.0}
  dances = {"w1": ("waltz", 2.0 * 2, "a.ogg"), "w2": ("waltz", 2.0 * 2, "b.ogg"),
            "c1": ("cha-cha", 1.0 * 2, "c.ogg"), "s1": ("salsa", 1.0, "")}
  for mid, (style, _, audio) in dances.items():
    np.savez(tmp_path / f"{mid}.npz", style=style, audio_path=audio)
  monkeypatch.setattr(td, "MOTION_CACHE", tmp_path)

  class Clip:
    def __init__(self, positions):
      self.positions = positions

  # _dance's speed has half the swing period: swing at 2 x the intended speed period.
  monkeypatch.setattr(td, "load_warped_clip", lambda mid, ref: Clip(_dance(seconds=40, period=dances[mid][1],
                                                                           sway=0.0)))
  assert td.dance_period_beats(list(dances), refs) == {"cha-cha": 2, "waltz": 3}


def test_style_probe_tells_raised_arms_from_a_hold():
  from training.experiments import style_probe
  def style_dance(raised: bool, seed: int):
    pos = _dance(seconds=20, seed=seed, period=0.8 + 0.1 * seed)
    for j in (J["left_wrist"], J["right_wrist"], J["left_hand"], J["right_hand"]):
      pos[:, j, 1] += 0.45 if raised else 0.0
    return evaluate.Dance(f"d{seed}", pos, style="cha-cha" if raised else "waltz")
  train = [style_dance(k % 2 == 0, k) for k in range(6)]
  x, y, names = style_probe.dance_segments(train)
  assert x.shape == (12, style_probe.DESCRIPTOR_DIMS) and len(y) == len(names) == 12
  probe = style_probe.StyleProbe(x, y)
  test = [style_dance(True, 11), style_dance(False, 12)]
  xt, yt, _ = style_probe.dance_segments(test)
  assert probe.predict(xt) == yt
  r = style_probe.report("synthetic", yt, probe.predict(xt))
  assert r["accuracy"] == 1.0 and r["confusion"][0][0] == 2 and r["confusion"][3][3] == 2
  # Swapping the labels swaps the calls: the probe learns from the labels, not from a fixed rule.
  flipped = style_probe.StyleProbe(x, ["waltz" if s == "cha-cha" else "cha-cha" for s in y])
  assert yt == ["cha-cha", "cha-cha", "waltz", "waltz"]
  assert flipped.predict(xt) == ["waltz", "waltz", "cha-cha", "cha-cha"]
  with pytest.raises(ValueError):
    style_probe.StyleProbe(x, ["waltz"] * len(y))


def test_style_reach_is_one_for_the_reference_and_zero_for_a_blend():
  from training.experiments.fid_parts import style_reach
  rng = np.random.default_rng(0)
  ref = np.concatenate([rng.normal(2.0, 0.3, (20, 4)), rng.normal(-1.0, 0.3, (40, 4))])
  rows = [{"dance": "tang_DANCE_C_1"}] * 20 + [{"dance": "tang_DANCE_W_1"}] * 40
  assert style_reach(ref, rows, ref, rows) == pytest.approx({"C": 1.0, "W": 1.0})
  blend = np.repeat(ref.mean(0, keepdims=True), 60, axis=0)  # every style danced as the average dance
  assert style_reach(ref, rows, blend, rows) == pytest.approx({"C": 0.0, "W": 0.0}, abs=1e-9)
  # a cha-cha halfway to the average; a style the reference lacks is not scored
  half = np.concatenate([ref[:20] * 0.5 + ref.mean(0) * 0.5, rng.normal(0, 1, (5, 4))])
  got = style_reach(ref, rows, half, rows[:20] + [{"dance": "tang_DANCE_X_1"}] * 5)
  assert got == pytest.approx({"C": 0.5})


def test_on_real_spans_cuts_each_dance_to_its_real_counterparts_song_time():
  # The real dance covers song time 14.9 s .. 14.9 + 20 s; the generated one the whole song from 0.133 s.
  real = [evaluate.Dance("a", _dance(seed=1, seconds=20), audio_offset_s=14.9),
          evaluate.Dance("b", _dance(seed=2, seconds=30), audio_offset_s=0.0)]
  gen_a = _dance(seed=3, seconds=60)
  gen = [evaluate.Dance("b", _dance(seed=4, seconds=25), audio_offset_s=0.133),
         evaluate.Dance("a", gen_a, audio_offset_s=0.133)]
  cut = {d.name: d for d in evaluate.on_real_spans(gen, real)}
  a0 = int(round((14.9 - 0.133) * 30))
  np.testing.assert_array_equal(cut["a"].positions, gen_a[a0:a0 + 600])
  assert cut["a"].audio_offset_s == pytest.approx(0.133 + a0 / 30)
  # A real span starting before the generated dance starts where the generated one does; a generated dance
  # that ends first keeps what it has.
  assert len(cut["b"].positions) == 25 * 30 and cut["b"].audio_offset_s == pytest.approx(0.133)
  with pytest.raises(ValueError, match="no real dance named c"):
    evaluate.on_real_spans([evaluate.Dance("c", gen_a)], real)
  # The real dances on their own spans are themselves: their FID against a reference is unchanged.
  ev = evaluate.Evaluator(real + [evaluate.Dance(f"r{i}", _dance(seed=10 + i, seconds=30)) for i in range(4)], real)
  assert ev.fid_div(evaluate.on_real_spans(real, real))["fid_k"] == pytest.approx(ev.evaluate(real)["fid_k"])


def test_leave_one_out_removes_each_song_from_both_sides():
  from training.experiments.fid_parts import leave_one_out
  real = [evaluate.Dance(n, _dance(seed=i, seconds=30, period=0.8 + 0.1 * i)) for i, n in enumerate("abc")]
  ev = evaluate.Evaluator([evaluate.Dance(f"r{i}", _dance(seed=10 + i, seconds=30)) for i in range(5)], real)
  val = evaluate.segment_table(real, beats_of=lambda d: np.zeros(0))
  gen = [evaluate.Dance(n, _dance(seed=20 + i, seconds=30, period=1.3)) for i, n in enumerate("abc")]
  draws = [evaluate.segment_table(gen, beats_of=lambda d: np.zeros(0))]
  rows = {r["without"]: r for r in leave_one_out(ev, val, draws)}
  assert list(rows) == ["none", "a", "b", "c"]
  assert rows["none"]["real_k"] == pytest.approx(ev.evaluate(real)["fid_k"])
  assert rows["none"]["model_k"] == pytest.approx(ev.fid_div(gen)["fid_k"])
  assert rows["b"]["real_g"] == pytest.approx(ev.fid_div([real[0], real[2]])["fid_g"])
  assert rows["b"]["model_k"] == pytest.approx(ev.fid_div([gen[0], gen[2]])["fid_k"])
  assert rows["b"]["excess_k"] == pytest.approx(rows["b"]["model_k"] - rows["b"]["real_k"])


def test_song_mean_swap_separates_song_averages_from_the_spread_within_songs():
  from training.experiments.fid_parts import song_mean_swap
  names = ["tang_DANCE_C_1", "tang_DANCE_W_1", "tang_DANCE_W_2"]
  real = [evaluate.Dance(n, _dance(seed=i, seconds=40, period=0.8 + 0.1 * i)) for i, n in enumerate(names)]
  ref = [evaluate.Dance(f"tang_DANCE_{s}_{i + 5}", _dance(seed=10 + i, seconds=30, period=0.7 + 0.15 * i))
         for i, s in enumerate("CCWWW")]
  ev = evaluate.Evaluator(ref, real)
  val = evaluate.segment_table(real, beats_of=lambda d: np.zeros(0))
  vn = np.array([r["dance"] for r in val["rows"]])
  # A model whose every song is the real dance shifted by its own offset: right spread, wrong averages.
  rng = np.random.default_rng(0)
  shift = {n: (rng.normal(0, 3, val["kinetic"].shape[1]), rng.normal(0, 0.2, val["geometric"].shape[1]))
           for n in names}
  gen = dict(val, kinetic=val["kinetic"] + np.stack([shift[n][0] for n in vn]),
             geometric=val["geometric"] + np.stack([shift[n][1] for n in vn]))
  out = song_mean_swap(ev, val, [gen])
  for kind in "kg":
    ref_x, norm, key = (ev.ref_k, ev.norm_k, "kinetic") if kind == "k" else (ev.ref_g, ev.norm_g, "geometric")
    assert out[kind]["real"] == pytest.approx(metrics.frechet_distance(ref_x, norm.apply(val[key])))
    assert out[kind]["model"] == pytest.approx(metrics.frechet_distance(ref_x, norm.apply(gen[key])))
    # Moved to the real averages, the model is the real set; the real set moved to the model's is the model.
    assert out[kind]["model_within_real_means"] == pytest.approx(out[kind]["real"], rel=1e-4)
    assert out[kind]["real_within_model_means"] == pytest.approx(out[kind]["model"], rel=1e-4)
    assert out[kind]["model"] > out[kind]["real"] + 1.0
  for n in names:
    dist = np.linalg.norm(shift[n][0] / ev.norm_k.std)
    assert out["per_song"][n]["model_real"] == pytest.approx(dist, rel=1e-4)
  with pytest.raises(ValueError, match="cover the real dances' songs"):
    song_mean_swap(ev, val, [dict(gen, rows=[{"dance": "other"}] * len(vn))])


def test_free_run_feeds_the_models_own_draws_and_teacher_forcing_the_real_codes():
  import types
  import torch
  from training.experiments.free_run import free_running_draws, teacher_forced_draws
  k = 8

  def peaked(codes):  # logits that put all the mass on (input code + 1) mod K
    return torch.nn.functional.one_hot((codes + 1) % k, k).float() * 100.0

  class Successor:  # a stand-in sequence model: the next code is the input code + 1
    cfg = types.SimpleNamespace(codebook_size=k, n_styles=2)

    def __call__(self, music, pre, u, l, style_w):
      return peaked(u), peaked(l)

    def step(self, music, pre, u, l, style_w, state):
      lu, ll = peaked(u), peaked(l)
      if style_w[0, -1] == 1:  # the unconditional pass of style guidance: a flat prediction
        lu, ll = torch.zeros_like(lu), torch.zeros_like(ll)
      return lu, ll, (state or 0) + 1

  real = np.array([5, 2, 6, 6, 1, 3, 0])
  t = {"music": np.zeros((7, 4)), "pre": np.zeros((7, 2)), "upper": real, "lower": real[::-1].copy(), "style": 0}
  gen = torch.Generator().manual_seed(0)
  tu, tl = teacher_forced_draws(Successor(), t, 3, gen)
  # step 0 reads BOS (K), every later step the real code before it
  np.testing.assert_array_equal(tu, np.tile((np.r_[k, real[1:6]] + 1) % k, (3, 1)))
  np.testing.assert_array_equal(tl, np.tile((np.r_[k, real[::-1][1:6]] + 1) % k, (3, 1)))
  for w in (1.0, 3.0):
    fu, fl = free_running_draws(Successor(), t, 2, gen, guidance=w)
    np.testing.assert_array_equal(fu, np.tile(np.arange(1, 7), (2, 1)))  # BOS -> 1 -> 2 ...: its own draws
    np.testing.assert_array_equal(fl, fu)

  class Habit(Successor):  # reading only BOS (no history) it predicts code 3; otherwise the successor
    def step(self, music, pre, u, l, style_w, state):
      if bool((u == k).all()) and state is not None:
        return peaked(torch.full_like(u, 2)), peaked(torch.full_like(l, 2)), state + 1
      return super().step(music, pre, u, l, style_w, state)

  # h = 0: the history branch is not run. h = -2 inverts it: logits = 2 l_nh - l_c, so every draw is the
  # no-history prediction (3), which is only reachable when that branch reads BOS for every input code.
  fu, _ = free_running_draws(Habit(), t, 2, gen, history_guidance=0.0)
  np.testing.assert_array_equal(fu, np.tile(np.arange(1, 7), (2, 1)))
  fu, fl = free_running_draws(Habit(), t, 2, gen, history_guidance=-2.0, history_mask=1.0)
  np.testing.assert_array_equal(fu[:, 1:], np.full((2, 5), 3))
  np.testing.assert_array_equal(fl[:, 1:], np.full((2, 5), 3))
  # --fid pools draw i of every song into one set per draw (and the real decode once).
  from training.experiments.free_run import fid_of_sets

  class Names:
    def fid_div(self, dances):
      return {"dances": list(dances)}
  rows = [{"dances": {"real": [f"{s}r"], "teacher_forced": [f"{s}t0", f"{s}t1"],
                      "free_running": [f"{s}f0", f"{s}f1"]}} for s in ("a", "b")]
  sets = fid_of_sets(Names(), rows)
  assert [d["dances"] for d in sets["real"]] == [["ar", "br"]]
  assert [d["dances"] for d in sets["free_running"]] == [["af0", "bf0"], ["af1", "bf1"]]
  assert [d["dances"] for d in sets["teacher_forced"]] == [["at0", "bt0"], ["at1", "bt1"]]
  # With nothing masked the history branch reads the draws themselves: l_nh = l_c, no change.
  fu, _ = free_running_draws(Habit(), t, 2, gen, history_guidance=-2.0, history_mask=0.0)
  np.testing.assert_array_equal(fu, np.tile(np.arange(1, 7), (2, 1)))

  class Listener(Successor):  # reading the music mean (not the song's music) it predicts code 3
    music_mean = torch.ones(4)

    def step(self, music, pre, u, l, style_w, state):
      if bool((music == self.music_mean).all()):
        return peaked(torch.full_like(u, 2)), peaked(torch.full_like(l, 2)), (state or 0) + 1
      return super().step(music, pre, u, l, style_w, state)

  # m = 1: the mean-music lanes do not change the draws; m = 0: only they count (with style guidance on
  # both lanes); m = -1 would favour them twice over: every draw is 3 as well.
  for w in (1.0, 3.0):
    fu, _ = free_running_draws(Listener(), t, 2, gen, guidance=w, music_guidance=1.0)
    np.testing.assert_array_equal(fu, np.tile(np.arange(1, 7), (2, 1)))
    for m in (0.0, -1.0):
      fu, fl = free_running_draws(Listener(), t, 2, gen, guidance=w, music_guidance=m)
      np.testing.assert_array_equal(fu, np.full((2, 6), 3))
      np.testing.assert_array_equal(fl, np.full((2, 6), 3))


def test_real_spread_draws_the_validations_composition_and_ranks_an_outlying_set_high():
  from training.experiments import real_spread
  rng = np.random.default_rng(0)
  ids = ([f"tang_DANCE_W_{i}" for i in range(10)] + [f"tang_DANCE_C_{i}" for i in range(4)] +
         [f"tang_DANCE_R_{i}" for i in range(4)] + ["tang_DANCE_T_5_a", "tang_DANCE_T_5_b"])
  validation = ["tang_DANCE_C_0", "tang_DANCE_R_0", "tang_DANCE_T_5_b", "tang_DANCE_W_0", "tang_DANCE_W_1"]
  # Every song from one distribution, but the validation's cha-cha, rumba and waltzes danced far off it.
  shifted = [v for v in validation if v != "tang_DANCE_T_5_b"]
  tables = {i: {"kinetic": rng.standard_normal((6, 3)) + (3.0 if i in shifted else 0.0),
                "geometric": rng.standard_normal((6, 2))} for i in ids}
  sets = real_spread.random_sets(ids, validation, 50, seed=1)
  for s in sets:
    assert s[0] == "tang_DANCE_T_5_b" and "tang_DANCE_T_5_a" not in s and len(set(s)) == len(s) == 5
    assert sorted(real_spread.style_letter(i) for i in s[1:]) == ["C", "R", "W", "W"]
  assert len({tuple(s) for s in sets}) > 10
  r = real_spread.spread(tables, validation, 200, seed=1, compare=(0.0, 1e9))
  assert r["fid_k"]["share_at_least_compare"] == 1.0 and r["fid_g"]["share_at_least_compare"] == 0.0
  assert r["fid_k"]["official_percentile"] > 95 and r["official"]["fid_k"] > r["fid_k"]["p90"]
  # The geometric features do not single the validation set out.
  assert 5 < r["fid_g"]["official_percentile"] < 95
