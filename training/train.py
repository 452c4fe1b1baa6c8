"""Trains the default model end to end on CPU and exports it: the driver of the training pipeline.

    OMP_WAIT_POLICY=PASSIVE /usr/bin/python3 -m training.train            # everything, resumable
    /usr/bin/python3 -m training.train --stages seq,eval,export --run training/runs/default

The flags are parsed once into a RunConfig (training.run_config; `--help` lists them) and the stages run in
order (training/stages): data (the motion cache), vq (both pose VQ-VAEs), vqdec (their decoders fine-tuned
with an energy term, codes unchanged), seq (the sequence model: on the engine's tempo clock, --tempo-ref
default 105 BPM, the dance is learned in tempo-normalised time after a fixed-rate phase; --tempo-ref 0 = the
fixed-rate model with tempo augmentation), export (models/default.dncw + tests/golden/default), owndec (the
decoders fitted to the model's own codes through the engine, then export again), eval (losses, music-ablation
gap; tempo following and the metric table of the exported model run by the engine). Every stage checkpoints
into the run directory and is skipped or resumed when its outputs exist, so the same command resumes a
stopped run; --stages runs a subset. The log is <run>/train.log, curves <run>/training_{vq,seq}.png
(`python3 -m training.plots RUN --out docs/images` for the docs). The manual: docs/training.md.
"""
from __future__ import annotations

import argparse
import os
import pathlib
import time

import torch

from training.common import clips as td
from training.common.run_dir import Logger, load_vqs, own_decoder
from training.export import load_models
from training.features.extract import FEATURE_DIMS
from training.plots import plot_run
from training.run_config import PARTS, STAGES, RunConfig
from training.stages import data, export, owndec, seq, vq, vqdec
from training.stages import eval as evaluation

D = RunConfig()  # the defaults


def parse_ranges(text: str) -> tuple[tuple[int, int], ...]:
  """'0:52,53:54' -> ((0, 52), (53, 54)): per-frame music feature column ranges [begin, end)."""
  out = []
  for part in text.split(","):
    try:
      b, e = (int(x) for x in part.split(":"))
    except ValueError:
      raise argparse.ArgumentTypeError(f"bad range '{part}' (want BEGIN:END)") from None
    if not 0 <= b < e <= FEATURE_DIMS:
      raise argparse.ArgumentTypeError(f"range {b}:{e} outside 0:{FEATURE_DIMS} or empty")
    out.append((b, e))
  return tuple(out)


def parse_style_weights(text: str) -> dict[str, float]:
  """'waltz=0,tango=4' -> {"waltz": 0.0, "tango": 4.0}: known style names (clips.ALL_STYLES), each weight
  in 0..100 (the engine's range for time_base.style_period_lock); '' -> {}."""
  out = {}
  for part in filter(None, (p.strip() for p in text.split(","))):
    name, sep, value = part.partition("=")
    if not sep or name not in td.ALL_STYLES:
      raise ValueError(f"'{part}' is not STYLE=B with STYLE one of {', '.join(td.ALL_STYLES)}")
    try:
      weight = float(value)
    except ValueError:
      weight = float("nan")
    if not 0.0 <= weight <= 100.0:
      raise ValueError(f"'{part}': the weight must be a number in 0..100")
    out[name] = weight
  return out


def parse_part_weights(text: str) -> dict[str, float]:
  """'0.3' -> both VQ-VAE parts 0.3; 'upper=0.1,lower=0.3' -> per part (a part not named gets 0); each >= 0."""
  text = text.strip()
  try:
    w = float(text)
  except ValueError:
    out = {"upper": 0.0, "lower": 0.0}
    for part in filter(None, (p.strip() for p in text.split(","))):
      name, sep, value = part.partition("=")
      try:
        out[name] = float(value) if sep and name in PARTS else float("nan")
      except ValueError:
        out[name] = float("nan")
      if not out[name] >= 0.0:
        raise ValueError(f"'{part}' is not upper=W or lower=W with W >= 0")
    return out
  if not w >= 0.0:
    raise ValueError(f"'{text}': the weight must be >= 0")
  return {"upper": w, "lower": w}


def _arg_type(parse, flag: str):
  """An argparse type from a parser raising ValueError: the error names the flag, exit code 2."""
  def convert(text: str):
    try:
      return parse(text)
    except ValueError as e:
      raise argparse.ArgumentTypeError(f"{flag}: {e}") from None
  convert.__name__ = flag
  return convert


def _ints(text: str) -> tuple[int, ...]:
  try:
    return tuple(int(x) for x in text.split(","))
  except ValueError:
    raise ValueError(f"must be comma-separated integers, got '{text}'") from None


def _floats(text: str) -> tuple[float, ...]:
  return tuple(float(f) for f in text.split(","))


def _names(text: str) -> tuple[str, ...]:
  return tuple(filter(None, text.split(",")))


def _periods(text: str) -> tuple[int, int]:
  try:
    periods = tuple(int(x) for x in text.split(","))
  except ValueError:
    periods = ()
  if len(periods) != 2 or not all(1 <= n <= 4 for n in periods):  # engine: kMaxPeriodLockPeriods
    raise ValueError(f"must be two integers in 1..4 (upper,lower), got '{text}'")
  return periods


def build_parser() -> argparse.ArgumentParser:
  """The command line: one flag per RunConfig field, the same name with dashes, its default the field's."""
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  add = ap.add_argument
  add("--run", type=pathlib.Path, default=D.run, help="the run directory (checkpoints, log, reports, curves)")
  add("--stages", type=_names, default=D.stages, help=f"comma-separated, of {','.join(STAGES)} (default: all)")
  add("--threads", type=int, default=D.threads)
  add("--vq-iters", type=int, default=D.vq_iters)
  add("--vq-width", type=int, default=D.vq_width)
  add("--vq-code-dim", type=int, default=D.vq_code_dim)
  add("--codebook-size", type=int, default=D.codebook_size)
  add("--vq-path-weight", type=float, default=D.vq_path_weight,
      help="lower-body VQ-VAE: weight of the integrated root path loss (common.vq_training.vq_loss)")
  add("--mirror", action="store_true",
      help="augment the sequence model's training dances with their left-right mirror images on the same music "
           "(the validation set is never mirrored)")
  add("--vq-mirror", action="store_true", help="augment the VQ-VAEs' training motion with its left-right mirror images")
  add("--vq-vel-weight", type=float, default=D.vq_vel_weight,
      help="VQ-VAEs: weight of the velocity term of the reconstruction loss")
  add("--vq-acc-weight", type=float, default=D.vq_acc_weight,
      help="VQ-VAEs: weight of the acceleration term of the reconstruction loss")
  add("--vq-dec-iters", type=int, default=D.vq_dec_iters,
      help="vqdec stage: iterations per decoder of the energy fine-tuning (0: no fine-tuning)")
  add("--vq-energy-weight", type=_arg_type(parse_part_weights, "--vq-energy-weight"), default=D.vq_energy_weight,
      help="vqdec stage: weight of the energy-matching term (common.decoder_tuning.energy_loss), one number for "
           "both parts or upper=W,lower=W (default upper=0.1,lower=0.3)")
  add("--vq-dec-lr", type=float, default=D.vq_dec_lr, help="vqdec stage: learning rate")
  add("--own-iters", type=int, default=D.own_iters,
      help="owndec stage: iterations of each decoder's fine-tuning on the model's own codes (0: no owndec stage)")
  add("--own-weight", type=_arg_type(parse_part_weights, "--own-weight"), default=D.own_weight,
      help="owndec stage: weight of the own-codes term (common.decoder_tuning.OwnCodes) per part, "
           "'upper=W,lower=W' or one W for both (default upper=1,lower=0); a part at 0 keeps its vqdec decoder")
  add("--own-anchor", type=float, default=D.own_anchor,
      help="owndec stage: weight of the posture anchor inside the own-codes term")
  add("--own-seeds", type=_arg_type(_ints, "--own-seeds"), default=D.own_seeds,
      help="owndec stage: engine seeds danced per training song (default 10,11)")
  add("--seq-iters", type=int, default=D.seq_iters,
      help="iterations of the sequence model (the tempo-normalised phase when pretraining; also the default of "
           "fixed-rate runs, --tempo-ref 0)")
  add("--pretrain-iters", type=int, default=D.pretrain_iters,
      help="tempo-normalised runs from scratch: first train the fixed-rate model on the tempo-augmented real-time "
           "pairs for this many iterations (0: none), then fine-tune it on the warped timeline at --finetune-lr")
  add("--finetune-lr", type=float, default=D.finetune_lr)
  add("--batch", type=int, default=D.batch)
  add("--val-every", type=int, default=D.val_every)
  add("--lr", type=float, default=D.lr)
  add("--seq-minutes", type=float, default=D.seq_minutes, help="stop seq training after this (0: no limit)")
  add("--d-model", type=int, default=D.d_model)
  add("--n-head", type=int, default=D.n_head)
  add("--lookahead", type=int, default=D.lookahead, help="0 anticipatory, 1 reactive")
  add("--code-mask", type=float, default=D.code_mask, help="past-motion dropout rate")
  add("--music-dropout", type=float, default=D.music_dropout,
      help="each training window's music stream replaced by the mean with this probability, PRE kept (both "
           "phases; trains the prediction music guidance contrasts with; off; 1 = the model never reads it, with "
           "--music-guidance 0)")
  add("--music-dropout-features", type=parse_ranges, default=D.music_dropout_features,
      help="B:E[,B:E...]: music dropout replaces only these per-frame feature columns [B, E) by the mean, the "
           "rest stays the song's (e.g. 0:52, the MFCCs, their deltas and the chroma); written into the model as "
           "sampling.music_guidance_features (default: every column)")
  add("--own-inputs", type=float, default=D.own_inputs,
      help="share of the sequence model's non-BOS input codes replaced by its own draws (parallel scheduled "
           "sampling; the tempo-normalised phase only when pretraining; default 0)")
  add("--own-passes", type=int, default=D.own_passes,
      help="with --own-inputs: repeat the replacement on the mixed inputs this many times, so inputs hold up to "
           "this many steps of the model's own drift (default 1)")
  add("--carry-state", action="store_true",
      help="train the sequence model on whole songs window by window with its state carried (common.lanes; the "
           "tempo-normalised phase only when pretraining)")
  add("--aux-steps", type=int, default=D.aux_steps,
      help="multi-step prediction: training-only heads also predict the codes 2..J steps ahead "
           "(common.seq_loss.AuxHeads; both phases; default 1: off)")
  add("--aux-weight", type=float, default=D.aux_weight, help="weight of the --aux-steps loss")
  add("--ema", type=float, default=D.ema,
      help="decay of an exponential average of the sequence model's weights, which is then exported (the "
           "tempo-normalised phase only when pretraining; default 0: off)")
  add("--style-balance", type=float, default=D.style_balance,
      help="sequence model: each style's share of the training windows goes as (its windows) ** B "
           "(common.tokens.window_probs): 1 = the data's shares (waltz ~58 %%, tango ~4 %%), 0 = equal")
  add("--self-tokens", type=pathlib.Path, default=D.self_tokens,
      help="filtered self-training: also train on these clips of the model's own kept draws "
           "(training.experiments.self_rollouts; with --init-model the model that drew them)")
  add("--self-share", type=float, default=D.self_share,
      help="with --self-tokens: their share of the training windows (default 0.5)")
  add("--dropout", type=float, default=D.dropout,
      help="sequence model: dropout on every residual branch's output, training only (not in the weights file; "
           "the engine and eval mode never drop)")
  add("--no-pre", action="store_true")
  add("--no-gate", action="store_true")
  add("--shared-mamba", action="store_true")
  add("--fold-tempo", action="store_true",
      help="tempo-normalised runs: the tempo features (tempogram, running tempo) of the warped timeline folded to "
           "the style's reference tempo (time_base.fold_tempo; docs/model.md section 1), so the model sees every "
           "song of a style at one tempo")
  add("--bar-clock", action="store_true",
      help="tempo-normalised runs: the bar clock replaces the beat tracker's bar phase (docs/model.md section 1); "
           "measured no better on tempo following (docs/research-log.md), so off by default")
  add("--period-lock", type=float, default=D.period_lock,
      help="tempo-normalised runs: the engine's default period lock weight written into the model "
           "(time_base.period_lock, with each style's dance period measured on the training dances; docs/model.md "
           "section 7); 0 = off")
  add("--style-period-lock", type=_arg_type(parse_style_weights, "--style-period-lock"),
      default=D.style_period_lock, metavar="STYLE=B[,STYLE=B...]",
      help="tempo-normalised runs: per-style period lock weights overriding --period-lock for sessions of that "
           "top style (time_base.style_period_lock, each 0..100; '' = none; default waltz=0); the waltzes here "
           "follow the tempo unlocked (docs/research-log.md)")
  add("--period-lock-sharpness", type=float, default=D.period_lock_sharpness,
      help="tempo-normalised runs: the period lock kernel's sharpness over code similarity "
           "(time_base.period_lock_sharpness, 1..100; the engine's default without the key is 20; docs/model.md "
           "section 6)")
  add("--period-lock-periods", type=_arg_type(_periods, "--period-lock-periods"), default=D.period_lock_periods,
      metavar="UPPER,LOWER",
      help="tempo-normalised runs: how many dance periods back each stream's period lock reaches "
           "(time_base.period_lock_periods, integers 1..4; docs/model.md section 6; default 1,2); the lower body's "
           "2 repeats a two-period figure such as the waltz's box step")
  add("--guidance", type=float, default=D.guidance,
      help="the engine's default style guidance weight written into the model (sampling.guidance; docs/model.md "
           "section 6); 1 = off")
  add("--music-guidance", type=float, default=D.music_guidance,
      help="the engine's default music guidance weight written into the model (sampling.music_guidance; "
           "docs/model.md section 6; needs --music-dropout); 1 = off")
  add("--tempo-factors", type=_floats, default=D.tempo_factors,
      help="tempo augmentation of the fixed-rate phase: music and motion stretched together (default "
           + ",".join(f"{f:g}" for f in D.tempo_factors) + ")")
  add("--warp-tempo-factors", type=_floats, default=D.warp_tempo_factors,
      help="tempo-normalised phase: the music of every training clip also played at these speeds (the warped "
           "motion stays; its features carry the other tempo; clips.load_warped_clip; default 1)")
  add("--warp-tempo-styles", type=_names, default=D.warp_tempo_styles,
      help="with --warp-tempo-factors: only these styles' songs (comma-separated) get the other tempi (default: "
           "every style)")
  add("--vq-run", type=pathlib.Path, default=D.vq_run, help="take the VQ-VAEs from this run directory")
  add("--vq-model", type=pathlib.Path, default=D.vq_model, help="take the VQ-VAEs from this exported .dncw file")
  add("--init-model", type=pathlib.Path, default=D.init_model, help="fine-tune the sequence model of this .dncw file")
  add("--tempo-ref", type=float, default=D.tempo_ref,
      help="dance in tempo-normalised time at this BPM (engine TempoClock); 0: fixed 30 fps rate")
  add("--out", type=pathlib.Path, default=D.out, help="the exported model file (default models/default.dncw)")
  add("--weights-dtype", choices=("f16", "f32"), default=D.weights_dtype,
      help="export: f16 = big matrices as binary16 (training.export.f16_policy), f32 = all f32")
  add("--eval-songs", type=int, default=D.eval_songs)
  add("--model-id", default=D.model_id, help="export: the model id (default: <out stem>-<date>)")
  return ap


def parse_config(argv=None) -> RunConfig:
  """The RunConfig of a command line; exits with code 2 and a message naming the flag when it is invalid."""
  ap = build_parser()
  args = ap.parse_args(argv)
  config = RunConfig(**vars(args))
  try:
    config.validate()
  except ValueError as e:
    ap.error(str(e))
  return config


def pretrain(config: RunConfig, cfg, vqs: dict, log) -> RunConfig:
  """The fixed-rate phase of a from-scratch run (stages.seq.pretrain_config: seq and export into
  <run>/pretrain, skipped when its model file exists); returns the tempo-normalised phase's config."""
  phase = seq.pretrain_config(config)
  if not phase.out.is_file():
    phase.run.mkdir(parents=True, exist_ok=True)
    log(f"pretrain: fixed-rate phase, {phase.seq_iters} iterations on tempo factors {phase.tempo_factors}")
    seq.run(phase, cfg, vqs, log)
    export.run(phase, vqs, log)
  return seq.after_pretrain(config, phase)


def run_stages(config: RunConfig, log) -> None:
  """The stages of config.stages, in the pipeline's order, each skipped or resumed when its outputs exist."""
  stages = config.stages
  if "data" in stages:
    data.run(config, log)
  if "vq" in stages and not vq.done(config):
    vq.run(config, log)
  if "vqdec" in stages and vqdec.wanted(config) and not vqdec.done(config):
    vqdec.run(config, log)
  if not any(s in stages for s in ("seq", "eval", "export")):
    return
  vqs = load_models(str(config.vq_model))[1] if config.vq_model else load_vqs(config.vq_dir)
  cfg = seq.seq_config(config, vqs)
  if "seq" in stages and seq.needs_pretrain(config):
    config = pretrain(config, cfg, vqs, log)
  if "seq" in stages:
    seq.run(config, cfg, vqs, log)
  base_vqs, vqs = vqs, own_decoder(vqs, config.run, config)  # the owndec decoders if they fit seq.pt and settings
  # Fixed-rate models are evaluated from the checkpoint (torch generator) and the report goes into the
  # export; tempo-normalised ones are evaluated from the exported file by the engine.
  if "eval" in stages and config.tempo_ref <= 0:
    evaluation.run(config, vqs, log)
  if "export" in stages:
    export.run(config, vqs, log)
  if "owndec" in stages and "export" not in stages:
    log("owndec: skipped (it dances the model the export stage writes: run it with --stages export,owndec)")
  if "owndec" in stages and "export" in stages and owndec.wanted(config) and not owndec.done(config):
    vqs = owndec.run(config, base_vqs, log)
    export.run(config, vqs, log)
  if "eval" in stages and config.tempo_ref > 0:
    evaluation.run(config, vqs, log)


def main(argv=None) -> int:
  config = parse_config(argv)
  torch.set_num_threads(config.threads)
  os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
  config.run.mkdir(parents=True, exist_ok=True)
  log = Logger(config.run / "train.log")
  log(f"start: stages {list(config.stages)}, args {config.as_log_dict()}")
  t0 = time.time()
  run_stages(config, log)
  plot_run(config.run, config.run)
  log(f"done in {(time.time() - t0) / 60:.1f} min; curves {config.run}/training_vq.png, "
      f"{config.run}/training_seq.png")
  return 0


if __name__ == "__main__":
  raise SystemExit(main())
