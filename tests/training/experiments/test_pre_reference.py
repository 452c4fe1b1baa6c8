"""The engine's incremental PRE (via the CLI) agrees with the batch Python reference to 1e-5."""
from __future__ import annotations

import numpy as np
import pytest

from training.features.extract import run_cli
from training.experiments.pre_reference import pre_batch_numpy, pre_batch_torch


@pytest.fixture(scope="module")
def song_outputs(features_cli, shared_data_dir, tmp_path_factory):
    songs = sorted(shared_data_dir.glob("tang2018/DANCE_*/audio.ogg"))
    if not songs:
        pytest.skip("no tang2018 songs in shared data")
    out = []
    for song in songs[:2]:
        d = tmp_path_factory.mktemp(song.parent.name)
        run_cli(song, d, cli=features_cli)
        out.append((np.load(d / "pre_input.npy"), np.load(d / "pre.npy")))
    return out


def test_numpy_reference_matches_engine(song_outputs):
    for pre_input, pre in song_outputs:
        assert pre.shape == (pre_input.shape[0], 128)
        ref = pre_batch_numpy(pre_input)
        assert np.abs(ref - pre).max() <= 1e-5


def test_torch_reference_matches_engine(song_outputs):
    torch = pytest.importorskip("torch")
    pre_input, pre = song_outputs[0]
    ref = pre_batch_torch(torch.from_numpy(pre_input)).numpy()
    assert np.abs(ref - pre).max() <= 1e-5
    # Batched input gives the same rows.
    batch = torch.from_numpy(np.stack([pre_input[:500], pre_input[100:600]]))
    out = pre_batch_torch(batch).numpy()
    assert np.abs(out[0] - pre[:500]).max() <= 1e-5


def test_reference_detects_a_wrong_alignment(song_outputs):
    """The comparison can fail: a one-frame shift of the input is far outside the tolerance."""
    pre_input, pre = song_outputs[0]
    shifted = np.concatenate([np.zeros((1, 4), np.float32), pre_input[:-1]])
    assert np.abs(pre_batch_numpy(shifted) - pre).max() > 1e-2


def test_phases_are_unit_vectors_where_energy_exists(song_outputs):
    _, pre = song_outputs[0]
    pairs = pre.reshape(pre.shape[0], 64, 2)
    norms = np.linalg.norm(pairs, axis=-1)
    assert norms.max() <= 1.0 + 1e-6
    assert np.median(norms[200:]) > 0.99
