"""The tempo-normalised training clips (training.common.clips.load_warped_clip) on a click track: the warped dance is
the same at every tempo factor (the engine's clock folds the stretched song to the reference), while the
music features carry the stretched tempo (tempo augmentation of the warped phase, --warp-tempo-factors)."""
import shutil
import wave

import numpy as np
import pytest

from training.common import clips as td
from training.data.skeleton import load_skeleton

BPM, SECONDS, SR = 120.0, 40.0, 24000


def _click_track(path):
  t = np.arange(int(SECONDS * SR)) / SR
  x = np.zeros_like(t)
  for k, b in enumerate(np.arange(0.25, SECONDS, 60.0 / BPM)):
    i = int(b * SR)
    n = min(len(t) - i, int(0.05 * SR))
    gain = 1.0 if k % 4 == 0 else 0.6
    x[i:i + n] += gain * np.sin(2 * np.pi * 1000 * t[:n]) * np.exp(-t[:n] / 0.01)
  with wave.open(str(path), "wb") as w:
    w.setnchannels(1)
    w.setsampwidth(2)
    w.setframerate(SR)
    w.writeframes((np.clip(x, -1, 1) * 0.5 * 32767).astype(np.int16).tobytes())


@pytest.fixture
def warp_setup(tmp_path, monkeypatch, features_cli, shared_data_dir):
  if shutil.which("sox") is None:
    pytest.skip("sox is not installed")
  for name in ("MOTION_CACHE", "FEATURE_CACHE", "STRETCH_CACHE"):
    (tmp_path / name).mkdir()
    monkeypatch.setattr(td, name, tmp_path / name)
  audio = tmp_path / "song" / "audio.wav"
  audio.parent.mkdir()
  _click_track(audio)
  # A dancer swaying sideways once every two beats (period 1 s), the whole song long.
  frames = int(SECONDS * 30)
  pos = np.repeat(load_skeleton().rest_positions()[None], frames, 0) + [0.0, 0.95, 0.0]
  pos[:, :, 0] += 0.2 * np.sin(2 * np.pi * np.arange(frames) / 30.0)[:, None]
  np.savez(tmp_path / "MOTION_CACHE" / "clicks.npz", positions=pos.astype(np.float32), style="cha-cha",
           audio_path=str(audio), audio_offset_s=0.0)
  return audio


def _sway_period(positions):
  """Frames per sideways sway of the pelvis (the peak of its spectrum)."""
  x = positions[:, 0, 0] - positions[:, 0, 0].mean()
  spectrum = np.abs(np.fft.rfft(x * np.hanning(len(x))))
  k = int(np.argmax(spectrum[1:])) + 1
  return len(x) / k


def test_warped_clip_keeps_the_dance_and_the_stretched_tempo(warp_setup):
  # At the reference 120 BPM the warped timeline runs 15 frames per beat whether the song plays at 120 or
  # (factor 0.8) 96 BPM: the sway, once per two beats, takes 30 warped frames.
  clips = {f: td.load_warped_clip("clicks", BPM, factor=f) for f in (1.0, 0.8)}
  for f, c in clips.items():
    assert c.factor == f and abs(c.audio_offset_s) < 1e-9
    assert c.audio_path.endswith("audio.wav") == (f == 1.0)
    # The same dance at any factor (the stretched song's frames map back to the dance's own frames; a clip
    # that forgot the factor would sway 1 / 0.8 times as slowly in warped time).
    sway = _sway_period(c.positions)
    assert abs(sway - 30.0) < 1.0, (f, sway)
    # The whole dance, ~80 beats at 15 warped frames each.
    assert abs(len(c.positions) - 1200) < 60, (f, len(c.positions))
  # The music features carry each song's own tempo: the running tempo (feature 104 = log2(BPM / 120)).
  tempo = {f: float(np.median(c.features[len(c.features) // 2:, 104])) for f, c in clips.items()}
  assert abs(tempo[1.0] - 0.0) < 0.05 and abs(tempo[0.8] - np.log2(0.8)) < 0.05, tempo


def test_fold_tempo_shows_every_factor_at_the_reference(warp_setup):
  # With fold_tempo the tempo features are folded to the reference (audio::FoldTempoFeatures): the song at
  # 96 BPM (factor 0.8) is shown at 120 BPM like the original, in its running tempo and in its tempogram;
  # the other features are the unfolded clip's.
  grams = {}
  for f in (1.0, 0.8):
    plain = td.load_warped_clip("clicks", BPM, factor=f)
    folded = td.load_warped_clip("clicks", BPM, factor=f, fold_tempo=True)
    np.testing.assert_array_equal(folded.positions, plain.positions)
    half = len(folded.features) // 2
    assert abs(float(np.median(folded.features[half:, td.TEMPO]))) < 0.01, f
    other = np.ones(108, bool)
    other[td.TEMPOGRAM:td.TEMPOGRAM + 48] = other[td.TEMPO] = False
    np.testing.assert_array_equal(folded.features[:, other], plain.features[:, other])
    if f == 0.8:  # unfolded, the stretched song's tempo shows (a check that the fold did something)
      assert abs(float(np.median(plain.features[half:, td.TEMPO])) - np.log2(0.8)) < 0.05
    grams[f] = {k: c.features[half:, td.TEMPOGRAM:td.TEMPOGRAM + 48].mean(0) for k, c in
                (("plain", plain), ("folded", folded))}
  # The beat's autocorrelation peak (away from the 60 BPM end, where the bar's accent also peaks): at the
  # original's 120 BPM (entry 23.5) in both folded clips, 7.6 entries lower in the stretched song unfolded.
  peak = {(f, k): 10 + int(np.argmax(g[k][10:])) for f, g in grams.items() for k in ("plain", "folded")}
  assert peak[(1.0, "folded")] in (23, 24) and peak[(0.8, "folded")] in (23, 24), peak
  assert peak[(1.0, "plain")] in (23, 24) and peak[(0.8, "plain")] in (15, 16, 17), peak
