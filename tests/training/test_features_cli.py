"""The dance-features CLI on real songs: shapes, metadata, summary, chunking invariance, bad input."""
from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from training.features.extract import FEATURE_DIMS, PRE_DIMS, extract_features, run_cli


@pytest.fixture(scope="module")
def song(shared_data_dir):
    songs = sorted(shared_data_dir.glob("tang2018/DANCE_*/audio.ogg"))
    if not songs:
        pytest.skip("no tang2018 songs in shared data")
    return songs[0]


def test_summary_and_shapes(features_cli, song, tmp_path):
    summary = run_cli(song, tmp_path, cli=features_cli)
    feats = np.load(tmp_path / "features.npy")
    pre = np.load(tmp_path / "pre.npy")
    assert feats.dtype == np.float32 and pre.dtype == np.float32
    assert feats.shape == (summary["frames"], FEATURE_DIMS)
    assert pre.shape == (summary["frames"], PRE_DIMS)
    assert abs(summary["frames"] - summary["duration_s"] * 30) <= 1
    assert np.isfinite(feats).all() and np.isfinite(pre).all()
    assert 60 <= summary["tempo_bpm"] <= 250
    beats = np.asarray(summary["beats_s"])
    assert len(beats) > summary["duration_s"]  # more than one beat per second over a dance song
    # The beat clock's step is clamped to [0.5, 1.5] x the tempo, so beats are >= 2/3 period apart (<= 250 BPM).
    assert np.all(np.diff(beats) > 0.15)
    meta = json.loads((tmp_path / "features.npy.json").read_text())
    assert meta["dims"] == FEATURE_DIMS and meta["pre"]["dims"] == PRE_DIMS
    covered = sorted((f["begin"], f["end"]) for f in meta["features"])
    assert covered[0][0] == 0 and covered[-1][1] == FEATURE_DIMS
    assert all(a[1] == b[0] for a, b in zip(covered, covered[1:]))


def test_chunk_size_does_not_change_output(features_cli, song, tmp_path):
    run_cli(song, tmp_path / "a", chunk_samples=4096, cli=features_cli)
    run_cli(song, tmp_path / "b", chunk_samples=333, cli=features_cli)
    for name in ("features.npy", "pre.npy"):
        a, b = np.load(tmp_path / "a" / name), np.load(tmp_path / "b" / name)
        assert a.shape == b.shape
        assert np.abs(a - b).max() <= 1e-6


def test_cache_returns_the_same_arrays(features_cli, song, tmp_path):
    first = extract_features(song, cache_dir=tmp_path)
    second = extract_features(song, cache_dir=tmp_path)
    assert np.array_equal(first["features"], second["features"])
    assert len(list(tmp_path.iterdir())) == 1


@pytest.mark.parametrize("content,name", [(b"", "empty.wav"), (b"hello, not audio\n", "text.wav")])
def test_bad_files_give_a_clear_error(features_cli, tmp_path, content, name):
    path = tmp_path / name
    path.write_bytes(content)
    proc = subprocess.run([str(features_cli), str(path), "--summary"], capture_output=True, text=True)
    assert proc.returncode == 1
    assert "dance-features:" in proc.stderr and name in proc.stderr


def test_usage_errors(features_cli):
    proc = subprocess.run([str(features_cli)], capture_output=True, text=True)
    assert proc.returncode == 2 and "usage:" in proc.stderr
    proc = subprocess.run([str(features_cli), "x.wav", "--chunk-samples", "0", "--summary"],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "--chunk-samples" in proc.stderr


def test_clock_maps_warped_frames_to_the_running_tempo(features_cli, song, tmp_path):
    """`--clock`: every warped frame has one source frame, in order; per real frame the number of warped
    frames follows the running tempo folded into the reference octave (engine/audio/tempo_clock.h)."""
    ref = 105.0
    clock_path = tmp_path / "clock.npy"
    proc = subprocess.run([str(features_cli), str(song), "--out", str(tmp_path / "f.npy"), "--clock",
                           str(clock_path), "--tempo-ref", str(ref)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    feats = np.load(tmp_path / "f.npy")
    clock = np.load(clock_path).astype(np.float64)
    src, x = clock[:, 0], clock[:, 1]
    assert np.all(np.diff(src) >= 0) and np.all(np.diff(x) > 0)
    assert np.all((x >= src - 1e-3) & (x < src + 1 + 1e-3))  # float32 positions
    assert src[-1] <= len(feats) - 1
    # Warped frames per real frame = fold(tempo) / ref, checked over 10-s stretches whose tempo stays
    # clear of the octave edges (there the hysteresis may keep either octave).
    tempo = 120.0 * 2.0 ** feats[:, 104].astype(np.float64)
    counts = np.bincount(src.astype(np.int64), minlength=len(feats))
    checked = 0
    for a in range(0, len(feats) - 300, 300):
        octave = np.log2(tempo[a:a + 300] / ref)
        folded = tempo[a:a + 300] / 2.0 ** np.round(octave)
        if np.abs(octave - np.round(octave)).max() > 0.5 - 0.12:  # within ~9 % of an edge
            continue
        assert np.isclose(counts[a:a + 300].mean(), (folded / ref).mean(), rtol=0.01), a
        checked += 1
    assert checked >= 5


def test_clock_bar_phase_is_a_metronome_in_warped_time(features_cli, song, tmp_path):
    """`--clock --bar-beats B`: two more columns, (cos, sin) of 2 pi frac(j / L) with L = B beats at the
    reference tempo (audio::BarClockPhase); the first two columns are unchanged."""
    ref, beats = 86.0, 3
    plain, barred = tmp_path / "c2.npy", tmp_path / "c4.npy"
    for path, extra in ((plain, []), (barred, ["--bar-beats", str(beats)])):
        proc = subprocess.run([str(features_cli), str(song), "--clock", str(path), "--tempo-ref", str(ref)] + extra,
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
    c2, c4 = np.load(plain), np.load(barred)
    assert c2.shape[1] == 2 and c4.shape == (len(c2), 4)
    np.testing.assert_array_equal(c4[:, :2], c2)
    j = np.arange(len(c4), dtype=np.float64)
    bar = beats * 1800.0 / ref
    angle = 2 * np.pi * (j / bar % 1.0)
    np.testing.assert_allclose(c4[:, 2], np.cos(angle), atol=1e-6)
    np.testing.assert_allclose(c4[:, 3], np.sin(angle), atol=1e-6)
    proc = subprocess.run([str(features_cli), str(song), "--clock", str(barred), "--bar-beats", "0"],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "--bar-beats" in proc.stderr


def test_clock_refuses_a_bad_reference(features_cli, song, tmp_path):
    proc = subprocess.run([str(features_cli), str(song), "--clock", str(tmp_path / "c.npy"), "--tempo-ref", "0"],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "--tempo-ref" in proc.stderr


def test_clock_fold_tempo_columns_are_the_features_at_the_reference(features_cli, song, tmp_path):
    """`--clock --fold-tempo`: 49 more columns, the source frame's tempogram and tempo folded with its clock
    rate (audio::FoldTempoFeatures): the tempo is the reference times a power of two, and the tempogram is
    the source frame's moved along its log-tempo axis by the octaves the fold removed."""
    ref = 97.0
    feats_path, plain, folded = tmp_path / "f.npy", tmp_path / "c2.npy", tmp_path / "c51.npy"
    for path, extra in ((plain, ["--out", str(feats_path)]), (folded, ["--fold-tempo"])):
        proc = subprocess.run([str(features_cli), str(song), "--clock", str(path), "--tempo-ref", str(ref)] + extra,
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
    feats, c2, c = np.load(feats_path), np.load(plain), np.load(folded)
    assert c.shape == (len(c2), 2 + 48 + 1)
    np.testing.assert_array_equal(c[:, :2], c2)
    src = c[:, 0].astype(np.int64)
    tempo = c[:, 50].astype(np.float64)
    octaves = np.log2(120.0 * 2.0 ** tempo / ref)
    np.testing.assert_allclose(octaves, np.round(octaves), atol=1e-4)
    # The fold's rate from the two tempi, then the tempogram shifted by log2(rate) / (2 / 47) entries.
    log_rate = feats[src, 104].astype(np.float64) - tempo
    assert np.all(np.abs(log_rate) <= 0.5 + np.log2(1.08) + 1e-6)
    assert np.mean(np.abs(log_rate) > 0.01) > 0.5  # the song is not at the reference: the fold moves it
    grid = np.arange(48, dtype=np.float64)
    for j in range(0, len(c), 97):
        x = np.clip(grid + log_rate[j] / (2.0 / 47.0), 0, 47)
        np.testing.assert_allclose(c[j, 2:50], np.interp(x, grid, feats[src[j], 54:102]), atol=2e-5)
    proc = subprocess.run([str(features_cli), str(song), "--out", str(feats_path), "--fold-tempo"],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "--fold-tempo needs --clock" in proc.stderr
