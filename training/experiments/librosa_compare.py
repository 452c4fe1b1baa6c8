"""Checks of the engine's features against ground truth and against librosa (tests and reports only).

librosa is the field's reference implementation; it is used here to compare, never at run time. Needs the
project venv (/work/main/.venv has librosa) and the Debian packages fretsonfire-songs-{sectoid,muldjord}
(8 songs whose notes.mid tempo maps give the true tempo) and python3-mido.

    songs = find_songs()                       # [(name, song.ogg, true_bpm)]
    row = compare_song(name, path, true_bpm)   # dict of the table's columns
    tone = compare_steady_tone()               # MFCC / chroma agreement on a steady harmonic tone
"""
from __future__ import annotations

import glob
import os
import tempfile
from pathlib import Path

import numpy as np

from training.features.extract import extract_features, run_cli

SONG_ROOTS = ["/usr/share/games/fretsonfire/data/songs"]
FPS = 30.0
HOP = 800
SR = 24000
ONSET_INDEX = 52
MFCC = slice(0, 20)
CHROMA = slice(40, 52)
# Our power spectrum is |X|^2 * 4 / (sum of window)^2 (a full-scale sine peaks at 0 dB); librosa's is |X|^2.
POWER_SCALE = 4.0 / 1024.0 ** 2


def midi_tempo(path: str) -> tuple[float, int]:
    """(first tempo in BPM, number of distinct tempi) of a MIDI file's tempo map."""
    import mido

    tempi = []
    for track in mido.MidiFile(path).tracks:
        for msg in track:
            if msg.type == "set_tempo":
                tempi.append(round(mido.tempo2bpm(msg.tempo), 3))
    if not tempi:
        return 120.0, 0  # the MIDI default
    return tempi[0], len(set(tempi))


def find_songs() -> list[tuple[str, str, float]]:
    songs = []
    for root in SONG_ROOTS:
        for ini in sorted(glob.glob(os.path.join(root, "*", "*", "notes.mid"))):
            d = os.path.dirname(ini)
            if os.path.isfile(os.path.join(d, "song.ogg")):
                bpm, _ = midi_tempo(ini)
                songs.append((os.path.basename(d), os.path.join(d, "song.ogg"), bpm))
    return songs


def tempo_verdict(estimate: float, truth: float, tolerance: float = 0.04) -> str:
    """'ok' within tolerance, 'octave' if within tolerance of half/double, else 'wrong'."""
    if abs(estimate / truth - 1.0) <= tolerance:
        return "ok"
    for factor in (0.5, 2.0):
        if abs(estimate / (truth * factor) - 1.0) <= tolerance:
            return "octave"
    return "wrong"


def beat_f_measure(reference: np.ndarray, estimated: np.ndarray, window: float = 0.07) -> float:
    """F-measure of beat times with a +-window (s) tolerance, one-to-one matching (mir_eval's definition)."""
    reference = np.asarray(reference, dtype=float)
    estimated = np.asarray(estimated, dtype=float)
    if len(reference) == 0 or len(estimated) == 0:
        return 0.0
    used = np.zeros(len(estimated), dtype=bool)
    hits = 0
    for r in reference:
        d = np.abs(estimated - r)
        d[used] = np.inf
        j = int(np.argmin(d))
        if d[j] <= window:
            used[j] = True
            hits += 1
    precision, recall = hits / len(estimated), hits / len(reference)
    return 0.0 if hits == 0 else 2 * precision * recall / (precision + recall)


def _best_lag_correlation(a: np.ndarray, b: np.ndarray, max_lag: int = 3) -> tuple[float, int]:
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    best = (-2.0, 0)
    for lag in range(-max_lag, max_lag + 1):
        x = a[max(0, lag): n + min(0, lag)]
        y = b[max(0, -lag): n - max(0, lag)]
        c = float(np.corrcoef(x, y)[0, 1])
        best = max(best, (c, lag))
    return best


def compare_song(name: str, path: str, true_bpm: float, skip_s: float = 10.0) -> dict:
    import librosa

    ours = extract_features(path)
    s = ours["summary"]
    beats = np.asarray(s["beats_s"])
    beats = beats[beats >= skip_s]

    y, _ = librosa.load(path, sr=SR, mono=True)
    # Same frame grid as ours (hop 800, 2048 window, 64 mel bands); librosa centres frames, ours trail:
    # the best lag is reported beside the correlation.
    env = librosa.onset.onset_strength(y=y, sr=SR, hop_length=HOP, n_fft=2048, n_mels=64)
    corr, lag = _best_lag_correlation(ours["features"][:, ONSET_INDEX], env)
    # librosa's own beat tracker with its default settings (offline: it sees the whole song).
    y22, _ = librosa.load(path, sr=22050, mono=True)
    lib_tempo, lib_beats = librosa.beat.beat_track(y=y22, sr=22050, units="time")
    lib_tempo = float(np.atleast_1d(lib_tempo)[0])
    lib_beats = lib_beats[lib_beats >= skip_s]
    return {
        "song": name,
        "true_bpm": true_bpm,
        "ours_final_bpm": s["tempo_bpm"],
        "ours_median_bpm": s["tempo_median_bpm"],
        "ours_verdict": tempo_verdict(s["tempo_median_bpm"], true_bpm),
        "librosa_bpm": round(lib_tempo, 2),
        "librosa_verdict": tempo_verdict(lib_tempo, true_bpm),
        "onset_corr": round(corr, 3),
        "onset_lag_frames": lag,
        "beat_f_vs_librosa": round(beat_f_measure(lib_beats, beats), 3),
        "beats_ours": int(len(beats)),
        "beats_librosa": int(len(lib_beats)),
    }


def steady_tone(seconds: float = 3.0, f0: float = 440.0) -> np.ndarray:
    t = np.arange(int(seconds * SR)) / SR
    return (0.3 * np.sin(2 * np.pi * f0 * t) + 0.15 * np.sin(2 * np.pi * 2 * f0 * t)
            + 0.07 * np.sin(2 * np.pi * 3 * f0 * t)).astype(np.float32)


def compare_steady_tone(f0: float = 440.0) -> dict:
    """MFCC and chroma of a steady harmonic tone: ours vs librosa with the same STFT/mel settings."""
    import librosa
    import scipy.io.wavfile

    y = steady_tone(f0=f0)
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "tone.wav"
        scipy.io.wavfile.write(wav, SR, y)
        run_cli(wav, tmp)
        ours = np.load(Path(tmp) / "features.npy")
    steady = slice(10, -5)  # away from the start (zeros in the window) and the end
    our_mfcc = ours[steady, MFCC].mean(axis=0)
    our_chroma = ours[steady, CHROMA].mean(axis=0)

    power = np.abs(librosa.stft(y, n_fft=2048, hop_length=HOP, window="hann", center=False)) ** 2
    mel = librosa.feature.melspectrogram(S=power * POWER_SCALE, sr=SR, n_mels=64, htk=False, norm="slaney")
    lib_mfcc = librosa.feature.mfcc(S=librosa.power_to_db(mel, ref=1.0, amin=1e-10, top_db=None), n_mfcc=20)
    lib_mfcc = lib_mfcc[:, 2:-2].mean(axis=1)
    lib_chroma = librosa.feature.chroma_stft(S=power, sr=SR, tuning=0.0, norm=np.inf)[:, 2:-2].mean(axis=1)
    cos = float(our_chroma @ lib_chroma / (np.linalg.norm(our_chroma) * np.linalg.norm(lib_chroma)))
    return {
        "f0": f0,
        "mfcc_max_abs_diff": float(np.abs(our_mfcc - lib_mfcc).max()),
        "mfcc_rel_diff": float(np.linalg.norm(our_mfcc - lib_mfcc) / np.linalg.norm(lib_mfcc)),
        "chroma_argmax_ours": int(np.argmax(our_chroma)),
        "chroma_argmax_librosa": int(np.argmax(lib_chroma)),
        "chroma_cosine": round(cos, 4),
    }
