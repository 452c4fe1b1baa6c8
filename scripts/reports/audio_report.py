#!/usr/bin/env python3
"""Prints the audio front end's quality tables (markdown): tempo vs truth and agreement with librosa.

Usage: DANCE_BUILD_DIR=build .venv/bin/python scripts/reports/audio_report.py
Needs librosa (the project venv), python3-mido and the fretsonfire-songs-* Debian packages.
The tables are copied into docs/features.md.
"""
from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from training.experiments.librosa_compare import compare_song, compare_steady_tone, find_songs  # noqa: E402


def main() -> None:
    songs = find_songs()
    if not songs:
        sys.exit("no fretsonfire songs found: sudo apt-get install fretsonfire-songs-sectoid fretsonfire-songs-muldjord")
    rows = [compare_song(*s) for s in songs]
    print("### Tempo and beats on real music (8 fretsonfire songs, truth = notes.mid tempo map)\n")
    print("| song | true BPM | ours (median) | ours (final) | verdict | librosa BPM | librosa verdict |"
          " onset corr (lag) | beat F vs librosa |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['song']} | {r['true_bpm']:g} | {r['ours_median_bpm']:.1f} | {r['ours_final_bpm']:.1f} |"
              f" {r['ours_verdict']} | {r['librosa_bpm']:.1f} | {r['librosa_verdict']} |"
              f" {r['onset_corr']:.3f} ({r['onset_lag_frames']:+d}) | {r['beat_f_vs_librosa']:.3f} |")
    count = lambda key, v: sum(r[key] == v for r in rows)  # noqa: E731
    print(f"\nOurs: {count('ours_verdict', 'ok')}/{len(rows)} within 4 %, "
          f"{count('ours_verdict', 'octave')} octave errors, {count('ours_verdict', 'wrong')} other errors. "
          f"librosa: {count('librosa_verdict', 'ok')}/{len(rows)} within 4 %, "
          f"{count('librosa_verdict', 'octave')} octave errors, {count('librosa_verdict', 'wrong')} other.")
    mean = lambda key: sum(r[key] for r in rows) / len(rows)  # noqa: E731
    print(f"Mean onset-strength correlation with librosa: {mean('onset_corr'):.3f}; "
          f"mean beat F-measure vs librosa beats (+-70 ms, after 10 s): {mean('beat_f_vs_librosa'):.3f}.\n")
    print("### Steady harmonic tone (f0 + 2 harmonics, 3 s): ours vs librosa, same STFT and mel settings\n")
    print("| f0 (Hz) | MFCC max abs diff (dB) | MFCC relative diff | chroma argmax ours / librosa | chroma cosine |")
    print("|---|---|---|---|---|")
    for f0 in (98.0, 261.63, 440.0, 880.0):
        t = compare_steady_tone(f0)
        print(f"| {f0:g} | {t['mfcc_max_abs_diff']:.4f} | {t['mfcc_rel_diff']:.1e} |"
              f" {t['chroma_argmax_ours']} / {t['chroma_argmax_librosa']} | {t['chroma_cosine']:.4f} |")


if __name__ == "__main__":
    main()
