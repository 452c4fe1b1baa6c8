"""Runs the engine's `dance-features` CLI and caches its arrays.

The C++ extractor is the only feature implementation; this module never computes features itself.

    from training.features.extract import extract_features
    feats = extract_features("song.ogg")      # dict: features (T, 108), pre (T, 128), pre_input (T, 4),
                                              #       summary (dict from --summary)

The CLI is run by training.tools (found in $DANCE_BUILD_DIR/bin, else the repository's build/bin).
Results are cached under $DANCE_FEATURE_CACHE (default ~/.cache/dance-features), keyed by the audio file's
content hash and the CLI binary's hash, so a rebuilt extractor never serves stale arrays.

Command line: python -m training.features.extract AUDIO... [--out-dir DIR]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from training import tools

FEATURE_DIMS = 108
PRE_DIMS = 128
PRE_CHANNELS = 4
FPS = 30.0


FeatureToolMissing = tools.ToolMissing  # the dance-features binary was not found (build the project first)


def find_cli() -> Path:
    """The dance-features binary (training.tools.require), or FeatureToolMissing."""
    return tools.require("dance-features")


def _hash_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:16]


def run_cli(audio: str | os.PathLike, out_dir: str | os.PathLike, chunk_samples: int | None = None,
            cli: Path | None = None) -> dict:
    """Runs the CLI once, writing features.npy, pre.npy, pre_input.npy into out_dir; returns the summary."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stdout = tools.dance_features(audio, out=out_dir / "features.npy", pre=out_dir / "pre.npy",
                                  pre_input=out_dir / "pre_input.npy", summary=True, chunk_samples=chunk_samples,
                                  cli=cli)
    summary = json.loads(stdout.strip().splitlines()[-1])
    (out_dir / "summary.json").write_text(json.dumps(summary))
    return summary


def _load(out_dir: Path) -> dict:
    return {
        "features": np.load(out_dir / "features.npy"),
        "pre": np.load(out_dir / "pre.npy"),
        "pre_input": np.load(out_dir / "pre_input.npy"),
        "summary": json.loads((out_dir / "summary.json").read_text()),
    }


def extract_features(audio: str | os.PathLike, cache_dir: str | os.PathLike | None = None,
                     use_cache: bool = True) -> dict:
    """Features of one audio file: {"features", "pre", "pre_input", "summary"} (float32 arrays)."""
    audio = Path(audio)
    cli = find_cli()
    if not use_cache:
        with tempfile.TemporaryDirectory() as tmp:
            run_cli(audio, tmp, cli=cli)
            return _load(Path(tmp))
    cache_root = Path(cache_dir or os.environ.get("DANCE_FEATURE_CACHE",
                                                  Path.home() / ".cache" / "dance-features"))
    key = f"{_hash_file(audio)}-{_hash_file(cli)}"
    out_dir = cache_root / key
    if not (out_dir / "summary.json").is_file():
        tmp_dir = Path(tempfile.mkdtemp(dir=cache_root.mkdir(parents=True, exist_ok=True) or cache_root))
        run_cli(audio, tmp_dir, cli=cli)
        try:
            tmp_dir.rename(out_dir)
        except OSError:  # another process cached it first
            pass
    return _load(out_dir)


def extract_clock(audio: str | os.PathLike, reference_bpm: float,
                  cache_dir: str | os.PathLike | None = None, bar_beats: int = 0,
                  fold_tempo: bool = False) -> np.ndarray:
    """The engine's tempo clock over one audio file (`dance-features --clock`, engine/audio/tempo_clock.h):
    (warped frames, 2) float32, per warped frame its source feature frame and its real frame position;
    with bar_beats > 0, two more columns: (cos, sin) of the bar clock's phase at bar_beats beats per bar
    (audio::BarClockPhase); with fold_tempo, 49 more (last): the frame's `tempogram` (48) and `tempo`
    features folded to the reference tempo (audio::FoldTempoFeatures, `--fold-tempo`)."""
    audio = Path(audio)
    cli = find_cli()
    cache_root = Path(cache_dir or os.environ.get("DANCE_FEATURE_CACHE",
                                                  Path.home() / ".cache" / "dance-features"))
    out_dir = cache_root / f"{_hash_file(audio)}-{_hash_file(cli)}"
    out_dir.mkdir(parents=True, exist_ok=True)
    name = f"clock_{reference_bpm:g}" + (f"_bar{bar_beats}" if bar_beats > 0 else "") + ("_fold" if fold_tempo else "")
    path = out_dir / f"{name}.npy"
    if not path.is_file():
        tmp = out_dir / f".clock_{os.getpid()}.npy"
        tools.dance_features(audio, clock=tmp, tempo_ref=reference_bpm, bar_beats=bar_beats, fold_tempo=fold_tempo,
                             cli=cli)
        tmp.replace(path)
    return np.load(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("audio", nargs="+")
    parser.add_argument("--out-dir", help="also copy the arrays to OUT_DIR/<stem>_{features,pre}.npy")
    args = parser.parse_args()
    for a in args.audio:
        r = extract_features(a)
        s = r["summary"]
        print(f"{a}: {r['features'].shape[0]} frames, {s['duration_s']:.1f} s, tempo {s['tempo_bpm']} BPM")
        if args.out_dir:
            out = Path(args.out_dir)
            out.mkdir(parents=True, exist_ok=True)
            stem = Path(a).parent.name if Path(a).stem == "audio" else Path(a).stem
            np.save(out / f"{stem}_features.npy", r["features"])
            np.save(out / f"{stem}_pre.npy", r["pre"])


if __name__ == "__main__":
    main()
