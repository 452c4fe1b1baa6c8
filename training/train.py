"""Trains the default model end to end on CPU and exports it.

    OMP_WAIT_POLICY=PASSIVE /usr/bin/python3 -m training.train            # everything, resumable
    /usr/bin/python3 -m training.train --stages seq,eval,export --run training/runs/default

Stages: data (motion cache, via training.data.prepare if missing), vq (both pose VQ-VAEs), vqdec (their
decoders fine-tuned with an energy-matching term, encoders and codebooks frozen: training.train_vq_decoder), seq (features,
the engine's tempo clock (--tempo-ref, default 105 BPM: the dance is learned in tempo-normalised time;
--tempo-ref 0 = the fixed-rate model with tempo augmentation), tokens, the Danceba model), export
(models/default.dncw + tests/golden/default), eval (losses, music-ablation gap; tempo following and the
metric table of the exported model run by the engine). Every stage checkpoints into the run directory and is
skipped or resumed when its outputs exist; the log is <run>/train.log, curves <run>/training_{vq,seq}.png
(`python3 -m training.train_plots RUN --out docs/images` for the docs).
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

import numpy as np
import torch

from training import train_data as td
from training.model.config import SeqConfig, VQConfig

REPO = pathlib.Path(__file__).resolve().parents[1]


class Logger:
  def __init__(self, path: pathlib.Path):
    self.path = path
    path.parent.mkdir(parents=True, exist_ok=True)

  def __call__(self, msg: str) -> None:
    line = f"{time.strftime('%H:%M:%S')} {msg}"
    print(line, flush=True)
    with open(self.path, "a") as f:
      f.write(line + "\n")


def stage_vq(args, run: pathlib.Path, log: Logger) -> dict:
  from training.train_vq import train_vq, training_clips, validation_report
  # Decoders fine-tuned from an earlier VQ-VAE would not match the new codebooks: the vqdec stage redoes them.
  for stale in ("vqdec_upper.pt", "vqdec_lower.pt", "vqdec_report.json"):
    (run / stale).unlink(missing_ok=True)
  train = training_clips(args.vq_mirror)
  val = [td.load_clip(i, with_music=False) for i in td.load_split()["validation"]]
  log(f"vq: {len(train)} train clips ({sum(len(c.upper) for c in train)} frames), {len(val)} validation")
  vqs = {}
  for part, dim in (("upper", 45), ("lower", 31)):
    cfg = VQConfig(in_dim=dim, width=args.vq_width, code_dim=args.vq_code_dim,
                   codebook_size=args.codebook_size, path_weight=args.vq_path_weight,
                   vel_weight=args.vq_vel_weight, acc_weight=args.vq_acc_weight)
    arrays = [getattr(c, part) for c in train]
    vqs[part], hist = train_vq(part, arrays, cfg, args.vq_iters, run / f"vq_{part}.pt", log)
    (run / f"vq_{part}_history.json").write_text(json.dumps(hist))
  report = validation_report(vqs, val)
  log(f"vq validation: {json.dumps(report)}")
  (run / "vq_report.json").write_text(json.dumps(report, indent=1))
  return report


def stage_vqdec(args, run: pathlib.Path, log: Logger) -> dict:
  """Fine-tunes the decoders of <run>/vq_{part}.pt with the energy term (training.train_vq_decoder) into
  <run>/vqdec_{part}.pt (a part already written is skipped); the encoders and codebooks, and so the codes,
  are unchanged. Writes <run>/vqdec_report.json (the validation report of the fine-tuned pair)."""
  from training.train_vq import validation_report
  from training.train_vq_decoder import finetune_decoder, training_arrays
  vqs = load_vqs(run, fine_tuned=False)
  for part in ("upper", "lower"):
    path = run / f"vqdec_{part}.pt"
    if path.is_file():
      continue
    vq = vqs[part]
    t0 = time.time()
    hist = finetune_decoder(vq, part, training_arrays(part, args.vq_mirror), args.vq_dec_iters,
                            args.vq_energy_weight[part], lr=args.vq_dec_lr, log=log)
    tmp = path.with_suffix(".tmp")
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict(), "history": hist, "iter": args.vq_dec_iters,
                "finetune": {"energy_weight": args.vq_energy_weight[part], "lr": args.vq_dec_lr}}, tmp)
    os.replace(tmp, path)
    log(f"vqdec-{part}: {args.vq_dec_iters} iterations in {time.time() - t0:.0f} s -> {path}")
  val = [td.load_clip(i, with_music=False) for i in td.load_split()["validation"]]
  report = validation_report(load_vqs(run), val)
  report["energy_weight"], report["iters"] = args.vq_energy_weight, args.vq_dec_iters
  log(f"vqdec validation: {json.dumps(report)}")
  (run / "vqdec_report.json").write_text(json.dumps(report, indent=1))
  return report


def load_vqs(run: pathlib.Path, fine_tuned: bool = True, own: bool = False):
  """The run's VQ-VAEs; with fine_tuned, a part's vqdec_{part}.pt (decoder fine-tuned) when it exists; with
  own too, a part's owndec_{part}.pt when it was made for the run's current sequence model
  (own_decoder)."""
  from training.model.vqvae import PoseVQVAE
  vqs = {}
  for part in ("upper", "lower"):
    path = run / f"vqdec_{part}.pt"
    ck = torch.load(path if fine_tuned and path.is_file() else run / f"vq_{part}.pt")
    vq = PoseVQVAE(VQConfig.from_dict(ck["cfg"]))
    vq.load_state_dict(ck["model"])
    vqs[part] = vq.eval()
  return own_decoder(vqs, run) if fine_tuned and own else vqs


def seq_digest(run: pathlib.Path) -> str | None:
  """sha256 of the run's sequence model checkpoint (None without one): the owndec stage's decoder is valid
  only for the model whose codes it was fine-tuned on."""
  import hashlib
  path = run / "seq.pt"
  return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def owndec_dance_settings(args, run: pathlib.Path) -> dict:
  """What the owndec stage's engine dances depend on besides the sequence model: the exported file's
  time_base and sampling metadata (period lock, style tempi, guidance) and the seeds."""
  from training.train_seq import sampling_meta, time_base_meta
  return {"time_base": time_base_meta(args, run, lambda *_: None),
          "sampling": sampling_meta(args),
          "seeds": [int(s) for s in args.own_seeds]}


def own_parts(args) -> list[str]:
  """The parts whose decoder the owndec stage fits: those with an own-codes weight above 0."""
  return [part for part in ("upper", "lower") if args.own_weight[part] > 0]


def owndec_finetune_settings(args) -> dict:
  """The owndec stage's fine-tuning options (recorded in its checkpoints and report)."""
  parts = own_parts(args)
  return {"iters": args.own_iters, "own_weight": {p: args.own_weight[p] for p in parts},
          "own_anchor": args.own_anchor, "energy_weight": {p: args.vq_energy_weight[p] for p in parts},
          "lr": args.vq_dec_lr, "seeds": [int(s) for s in args.own_seeds]}


def owndec_settings(args, run: pathlib.Path) -> dict:
  """What the owndec stage's decoder depends on besides the sequence model: its dances' settings and the
  fine-tuning's own."""
  return dict(owndec_dance_settings(args, run), **owndec_finetune_settings(args))


def _owndec_fits(saved: dict, run: pathlib.Path, args) -> bool:
  """A saved owndec report or checkpoint was made for the run's sequence model and, when args are given,
  with the same settings (owndec_settings): a change of the sampling metadata or of --own-* redoes it."""
  if saved.get("seq_sha256") != seq_digest(run):
    return False
  return args is None or saved.get("settings") == json.loads(json.dumps(owndec_settings(args, run)))


def owndec_current(run: pathlib.Path, args=None) -> dict | None:
  """<run>/owndec_report.json when it was written for the run's current sequence model (and, with args, the
  current settings: _owndec_fits), else None."""
  path = run / "owndec_report.json"
  if not path.is_file():
    return None
  report = json.loads(path.read_text())
  return report if _owndec_fits(report, run, args) else None


def own_decoder(vqs: dict, run: pathlib.Path, args=None) -> dict:
  """vqs with each part's decoder of <run>/owndec_{part}.pt when that file exists and was fine-tuned on the
  codes of the run's current sequence model (with args: and the current settings); other parts unchanged."""
  import copy
  out = dict(vqs)
  for part in ("upper", "lower"):
    path = run / f"owndec_{part}.pt"
    if not path.is_file():
      continue
    ck = torch.load(path)
    if not _owndec_fits(ck, run, args):
      continue
    out[part] = copy.deepcopy(vqs[part])
    out[part].load_state_dict(ck["model"])
    out[part].eval()
  return out


def own_dances_dir(args, run: pathlib.Path) -> pathlib.Path:
  """<run>/own_dances/, emptied first when its dances were made by another sequence model or with other
  settings (owndec_dance_settings); stamped with the current ones in settings.key (not *.json:
  train_vq_decoder.load_own_codes reads every JSON file there as a dance)."""
  import shutil
  dances = run / "own_dances"
  stamp = dances / "settings.key"
  key = json.dumps({"seq_sha256": seq_digest(run), **owndec_dance_settings(args, run)}, sort_keys=True)
  if dances.is_dir() and (not stamp.is_file() or stamp.read_text() != key):
    shutil.rmtree(dances)
  dances.mkdir(parents=True, exist_ok=True)
  stamp.write_text(key)
  return dances


def stage_owndec(args, vqs: dict, run: pathlib.Path, log: Logger) -> dict:
  """The decoders fine-tuned on the sequence model's own codes (training.train_vq_decoder.OwnCodes): the
  exported model (args.out) dances every Tang training song in its own style through the engine
  (dance-generate, seeds --own-seeds) into <run>/own_dances/, then each part with an --own-weight above 0
  (own_parts) has its decoder in `vqs` fine-tuned, from the same dances, with train_vq_decoder's loss (the
  vqdec stage's energy weight of the part) plus the part's --own-weight x the own-codes term. Writes
  <run>/owndec_{part}.pt and owndec_report.json, all keyed to the sequence model (seq_digest); returns vqs
  with the new decoders (the caller exports again)."""
  import copy

  from training.eval.engine_eval import generate_song
  from training.eval.engine_tempo import dance_generate_bin
  from training.train_vq import validation_report
  from training.train_vq_decoder import finetune_decoder, training_arrays
  if not dance_generate_bin().is_file():
    raise SystemExit(f"owndec: {dance_generate_bin()} not found: build the engine (cmake --build build) or set "
                     "DANCE_BUILD_DIR")
  digest = seq_digest(run)
  dances = own_dances_dir(args, run)
  ids = td.tang_ids(td.load_split()["train"])
  t0 = time.time()
  for seed in args.own_seeds:
    for mid in ids:
      out = dances / f"{mid}_s{seed}.json"
      if not out.is_file():
        tmp = dances / f"{mid}_s{seed}.tmp.json"
        generate_song(args.out, mid, tmp, seed, 1.0)
        os.replace(tmp, out)
  log(f"owndec: {len(ids)} training songs x {len(args.own_seeds)} seeds danced by the engine in "
      f"{time.time() - t0:.0f} s -> {dances}")
  settings = owndec_finetune_settings(args)
  full = json.loads(json.dumps(owndec_settings(args, run)))
  new, last = dict(vqs), {}
  for part in own_parts(args):
    vq = copy.deepcopy(vqs[part])
    t0 = time.time()
    hist = finetune_decoder(vq, part, training_arrays(part, args.vq_mirror), args.own_iters,
                            args.vq_energy_weight[part], lr=args.vq_dec_lr, log=log, own_dances=str(dances),
                            own_weight=args.own_weight[part], own_anchor=args.own_anchor)
    path = run / f"owndec_{part}.pt"
    tmp = path.with_suffix(".tmp")
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict(), "history": hist, "iter": args.own_iters,
                "finetune": settings, "seq_sha256": digest, "settings": full}, tmp)
    os.replace(tmp, path)
    log(f"owndec-{part}: {args.own_iters} iterations in {time.time() - t0:.0f} s -> {path}")
    new[part] = vq
    last[part] = hist[-1] if hist else None
  val = [td.load_clip(i, with_music=False) for i in td.load_split()["validation"]]
  report = dict(validation_report(new, val), **settings, seq_sha256=digest, settings=full, last=last)
  log(f"owndec validation: {json.dumps(report)}")
  (run / "owndec_report.json").write_text(json.dumps(report, indent=1))
  return new


def pretrain_seq(args, cfg, vqs, factors, run: pathlib.Path, vq_run: pathlib.Path, log: Logger) -> pathlib.Path:
  """The fixed-rate phase of a from-scratch run, in <run>/pretrain (resumable like every stage); returns
  its exported f32 model, the parent of the tempo-normalised phase."""
  import copy
  from training import train_seq
  sub = run / "pretrain"
  out = sub / "model.dncw"
  if out.is_file():
    return out
  a = copy.copy(args)
  a.run, a.out, a.vq_run = str(sub), str(out), str(vq_run)
  a.tempo_ref, a.seq_iters, a.init_model, a.weights_dtype = 0.0, args.pretrain_iters, None, "f32"
  a.model_id = "pretrain"  # an intermediate file: never the id given for the final export
  # own-code inputs, the weight average and the carried state: the tempo-normalised phase only (the
  # multi-step heads, --aux-steps, train in both phases)
  a.own_inputs, a.ema, a.carry_state = 0.0, 0.0, False
  a.self_tokens = None  # the model's own draws are on the warped timeline
  sub.mkdir(parents=True, exist_ok=True)
  log(f"pretrain: fixed-rate phase, {a.seq_iters} iterations on tempo factors {factors}")
  train_seq.stage_seq(a, cfg, vqs, factors, sub, log)
  train_seq.stage_export(a, vqs, sub, log)
  return out


def parse_ranges(text: str) -> list[tuple[int, int]]:
  """'0:52,53:54' -> [(0, 52), (53, 54)]: per-frame music feature column ranges [begin, end)."""
  from training.features.extract import FEATURE_DIMS
  out = []
  for part in text.split(","):
    try:
      b, e = (int(x) for x in part.split(":"))
    except ValueError:
      raise argparse.ArgumentTypeError(f"bad range '{part}' (want BEGIN:END)") from None
    if not 0 <= b < e <= FEATURE_DIMS:
      raise argparse.ArgumentTypeError(f"range {b}:{e} outside 0:{FEATURE_DIMS} or empty")
    out.append((b, e))
  return out


def parse_style_weights(text: str) -> dict[str, float]:
  """'waltz=0,tango=4' -> {"waltz": 0.0, "tango": 4.0}: known style names (train_data.ALL_STYLES), each weight
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
        out[name] = float(value) if sep and name in ("upper", "lower") else float("nan")
      except ValueError:
        out[name] = float("nan")
      if not out[name] >= 0.0:
        raise ValueError(f"'{part}' is not upper=W or lower=W with W >= 0")
    return out
  if not w >= 0.0:
    raise ValueError(f"'{text}': the weight must be >= 0")
  return {"upper": w, "lower": w}


def main(argv=None) -> int:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--run", default=str(REPO / "training" / "runs" / "default"))
  ap.add_argument("--stages", default="data,vq,vqdec,seq,export,owndec,eval")
  ap.add_argument("--threads", type=int, default=2)
  ap.add_argument("--vq-iters", type=int, default=6000)
  ap.add_argument("--vq-width", type=int, default=128)
  ap.add_argument("--vq-code-dim", type=int, default=64)
  ap.add_argument("--codebook-size", type=int, default=512)
  ap.add_argument("--vq-path-weight", type=float, default=0.0,
                  help="lower-body VQ-VAE: weight of the integrated root path loss (train_vq.vq_loss)")
  ap.add_argument("--mirror", action="store_true",
                  help="augment the sequence model's training dances with their left-right mirror images on "
                       "the same music (the validation set is never mirrored)")
  ap.add_argument("--vq-mirror", action="store_true",
                  help="augment the VQ-VAEs' training motion with its left-right mirror images")
  ap.add_argument("--vq-vel-weight", type=float, default=4.0,
                  help="VQ-VAEs: weight of the velocity term of the reconstruction loss")
  ap.add_argument("--vq-acc-weight", type=float, default=4.0,
                  help="VQ-VAEs: weight of the acceleration term of the reconstruction loss")
  ap.add_argument("--vq-dec-iters", type=int, default=1500,
                  help="vqdec stage: iterations per decoder of the energy fine-tuning (0: no fine-tuning)")
  ap.add_argument("--vq-energy-weight", default="upper=0.1,lower=0.3",
                  help="vqdec stage: weight of the energy-matching term (training.train_vq_decoder.energy_loss), "
                       "one number for both parts or upper=W,lower=W (docs/training.md: the upper body's 0.1)")
  ap.add_argument("--vq-dec-lr", type=float, default=1e-4, help="vqdec stage: learning rate")
  ap.add_argument("--own-iters", type=int, default=1000,
                  help="owndec stage: iterations of each decoder's fine-tuning on the model's own codes "
                       "(0: no owndec stage)")
  ap.add_argument("--own-weight", default="upper=1,lower=0",
                  help="owndec stage: weight of the own-codes term (training.train_vq_decoder.OwnCodes) per "
                       "part, 'upper=W,lower=W' or one W for both; a part at 0 keeps its vqdec decoder")
  ap.add_argument("--own-anchor", type=float, default=100.0,
                  help="owndec stage: weight of the posture anchor inside the own-codes term")
  ap.add_argument("--own-seeds", default="10,11", help="owndec stage: engine seeds danced per training song")
  ap.add_argument("--seq-iters", type=int, default=1000,
                  help="iterations of the sequence model (the tempo-normalised phase when pretraining; "
                       "also the default of fixed-rate runs, --tempo-ref 0)")
  ap.add_argument("--pretrain-iters", type=int, default=1600,
                  help="tempo-normalised runs from scratch: first train the fixed-rate model on the "
                       "tempo-augmented real-time pairs for this many iterations (0: none), then fine-tune it "
                       "on the warped timeline at --finetune-lr")
  ap.add_argument("--finetune-lr", type=float, default=3e-4)
  ap.add_argument("--batch", type=int, default=16)
  ap.add_argument("--val-every", type=int, default=100)
  ap.add_argument("--lr", type=float, default=1e-3)
  ap.add_argument("--seq-minutes", type=float, default=0, help="stop seq training after this (0: no limit)")
  ap.add_argument("--d-model", type=int, default=128)
  ap.add_argument("--n-head", type=int, default=2)
  ap.add_argument("--lookahead", type=int, default=0, help="0 anticipatory, 1 reactive")
  ap.add_argument("--code-mask", type=float, default=0.4, help="past-motion dropout rate")
  ap.add_argument("--music-dropout", type=float, default=0.0,
                  help="each training window's music stream replaced by the mean with this probability, PRE "
                       "kept (both phases; trains the prediction music guidance contrasts with; off; 1 = the "
                       "model never reads it, with --music-guidance 0)")
  ap.add_argument("--music-dropout-features", type=parse_ranges, default=None,
                  help="B:E[,B:E...]: music dropout replaces only these per-frame feature columns [B, E) by the "
                       "mean, the rest stays the song's (e.g. 0:52, the MFCCs, their deltas and the chroma); "
                       "written into the model as sampling.music_guidance_features (default: every column)")
  ap.add_argument("--own-inputs", type=float, default=0.0,
                  help="share of the sequence model's non-BOS input codes replaced by its own draws (parallel "
                       "scheduled sampling; the tempo-normalised phase only when pretraining; default 0)")
  ap.add_argument("--own-passes", type=int, default=1,
                  help="with --own-inputs: repeat the replacement on the mixed inputs this many times, so "
                       "inputs hold up to this many steps of the model's own drift (default 1)")
  ap.add_argument("--carry-state", action="store_true",
                  help="train the sequence model on whole songs window by window with its state carried "
                       "(training.train_lanes; the tempo-normalised phase only when pretraining)")
  ap.add_argument("--aux-steps", type=int, default=1,
                  help="multi-step prediction: training-only heads also predict the codes 2..J steps ahead "
                       "(train_seq.AuxHeads; both phases; default 1: off)")
  ap.add_argument("--aux-weight", type=float, default=0.5, help="weight of the --aux-steps loss")
  ap.add_argument("--ema", type=float, default=0.0,
                  help="decay of an exponential average of the sequence model's weights, which is then "
                       "exported (the tempo-normalised phase only when pretraining; default 0: off)")
  ap.add_argument("--style-balance", type=float, default=0.5,
                  help="sequence model: each style's share of the training windows goes as (its windows) ** B "
                       "(train_seq.window_probs): 1 = the data's shares (waltz ~58 %%, tango ~4 %%), 0 = equal")
  ap.add_argument("--self-tokens", default=None,
                  help="filtered self-training: also train on these clips of the model's own kept draws "
                       "(training.self_rollouts; with --init-model the model that drew them)")
  ap.add_argument("--self-share", type=float, default=0.5,
                  help="with --self-tokens: their share of the training windows (default 0.5)")
  ap.add_argument("--dropout", type=float, default=0.0,
                  help="sequence model: dropout on every residual branch's output, training only (not in the "
                       "weights file; the engine and eval mode never drop)")
  ap.add_argument("--no-pre", action="store_true")
  ap.add_argument("--no-gate", action="store_true")
  ap.add_argument("--shared-mamba", action="store_true")
  ap.add_argument("--fold-tempo", action="store_true",
                  help="tempo-normalised runs: the tempo features (tempogram, running tempo) of the warped "
                       "timeline folded to the style's reference tempo (time_base.fold_tempo; docs/model.md "
                       "section 1), so the model sees every song of a style at one tempo")
  ap.add_argument("--bar-clock", action="store_true",
                  help="tempo-normalised runs: the bar clock replaces the beat tracker's bar phase (docs/model.md "
                       "section 1); measured no better on tempo following (docs/training.md), so off by default")
  ap.add_argument("--period-lock", type=float, default=8.0,
                  help="tempo-normalised runs: the engine's default period lock weight written into the model "
                       "(time_base.period_lock, with each style's dance period measured on the training dances; "
                       "docs/model.md section 7); 0 = off")
  ap.add_argument("--style-period-lock", default="waltz=0", metavar="STYLE=B[,STYLE=B...]",
                  help="tempo-normalised runs: per-style period lock weights overriding --period-lock for "
                       "sessions of that top style (time_base.style_period_lock, each 0..100; '' = none); the "
                       "waltzes here follow the tempo unlocked (docs/training.md)")
  ap.add_argument("--period-lock-sharpness", type=float, default=10.0,
                  help="tempo-normalised runs: the period lock kernel's sharpness over code similarity "
                       "(time_base.period_lock_sharpness, 1..100; the engine's default without the key is 20; "
                       "docs/model.md section 6)")
  ap.add_argument("--period-lock-periods", default="1,2", metavar="UPPER,LOWER",
                  help="tempo-normalised runs: how many dance periods back each stream's period lock reaches "
                       "(time_base.period_lock_periods, integers 1..4; docs/model.md section 6); the lower "
                       "body's 2 repeats a two-period figure such as the waltz's box step")
  ap.add_argument("--guidance", type=float, default=3.0,
                  help="the engine's default style guidance weight written into the model (sampling.guidance; "
                       "docs/model.md section 6); 1 = off")
  ap.add_argument("--music-guidance", type=float, default=1.0,
                  help="the engine's default music guidance weight written into the model "
                       "(sampling.music_guidance; docs/model.md section 6; needs --music-dropout); 1 = off")
  ap.add_argument("--tempo-factors", default=",".join(str(f) for f in td.TEMPO_FACTORS),
                  help="tempo augmentation of the fixed-rate phase: music and motion stretched together")
  ap.add_argument("--warp-tempo-factors", default="1",
                  help="tempo-normalised phase: the music of every training clip also played at these speeds "
                       "(the warped motion stays; its features carry the other tempo; train_data.load_warped_clip)")
  ap.add_argument("--warp-tempo-styles", default="",
                  help="with --warp-tempo-factors: only these styles' songs (comma-separated) get the other "
                       "tempi ('' = every style)")
  ap.add_argument("--vq-run", default=None, help="take the VQ-VAEs from this run directory")
  ap.add_argument("--vq-model", default=None, help="take the VQ-VAEs from this exported .dncw file")
  ap.add_argument("--init-model", default=None, help="fine-tune the sequence model of this .dncw file")
  ap.add_argument("--tempo-ref", type=float, default=105.0,
                  help="dance in tempo-normalised time at this BPM (engine TempoClock); 0: fixed 30 fps rate")
  ap.add_argument("--out", default=str(REPO / "models" / "default.dncw"))
  ap.add_argument("--weights-dtype", choices=("f16", "f32"), default="f16",
                  help="export: f16 = big matrices as binary16 (training.export.f16_policy), f32 = all f32")
  ap.add_argument("--eval-songs", type=int, default=8)
  ap.add_argument("--model-id", default=None, help="export: the model id (default: <out stem>-<date>)")
  args = ap.parse_args(argv)
  if not 0.0 <= args.period_lock <= 100.0:
    ap.error(f"--period-lock must be in [0, 100], got {args.period_lock}")
  if not 1.0 <= args.period_lock_sharpness <= 100.0:
    ap.error(f"--period-lock-sharpness must be in [1, 100], got {args.period_lock_sharpness}")
  if args.warp_tempo_styles and [float(f) for f in args.warp_tempo_factors.split(",")] == [1.0]:
    ap.error("--warp-tempo-styles needs --warp-tempo-factors (other speeds than 1)")
  if args.fold_tempo and args.tempo_ref <= 0:
    ap.error("--fold-tempo needs the tempo-normalised timeline (--tempo-ref > 0)")
  for st in filter(None, args.warp_tempo_styles.split(",")):
    if st not in td.ALL_STYLES:
      ap.error(f"--warp-tempo-styles: unknown style '{st}' (known: {', '.join(td.ALL_STYLES)})")
  try:
    args.style_period_lock = parse_style_weights(args.style_period_lock)
  except ValueError as e:
    ap.error(f"--style-period-lock: {e}")
  try:
    args.vq_energy_weight = parse_part_weights(args.vq_energy_weight)
  except ValueError as e:
    ap.error(f"--vq-energy-weight: {e}")
  raw_periods = args.period_lock_periods
  try:
    args.period_lock_periods = [int(x) for x in raw_periods.split(",")]
  except ValueError:
    args.period_lock_periods = []
  if len(args.period_lock_periods) != 2 or not all(1 <= n <= 4 for n in args.period_lock_periods):  # engine: kMaxPeriodLockPeriods
    ap.error(f"--period-lock-periods must be two integers in 1..4 (upper,lower), got '{raw_periods}'")
  if not 0.0 <= args.guidance <= 100.0:
    ap.error(f"--guidance must be in [0, 100], got {args.guidance}")
  if not 0.0 <= args.music_guidance <= 100.0:
    ap.error(f"--music-guidance must be in [0, 100], got {args.music_guidance}")
  try:
    args.own_seeds = [int(x) for x in args.own_seeds.split(",")]
  except ValueError:
    ap.error(f"--own-seeds must be comma-separated integers, got '{args.own_seeds}'")
  try:
    args.own_weight = parse_part_weights(args.own_weight)
  except ValueError as e:
    ap.error(f"--own-weight: {e}")
  for name in ("own_iters", "own_anchor"):
    if getattr(args, name) < 0:
      ap.error(f"--{name.replace('_', '-')} must be >= 0, got {getattr(args, name)}")
  if not 0.0 <= args.ema < 1.0:
    ap.error(f"--ema must be in [0, 1), got {args.ema}")
  if not 1 <= args.aux_steps <= 16 or args.aux_weight < 0:
    ap.error(f"--aux-steps must be in 1..16 and --aux-weight >= 0, got {args.aux_steps}, {args.aux_weight}")
  if not 0.0 <= args.music_dropout <= 1.0:
    ap.error(f"--music-dropout must be in [0, 1], got {args.music_dropout}")
  if args.music_dropout == 1 and args.music_guidance != 0:
    ap.error("--music-dropout 1 trains a model that never reads the song's music (in the chosen columns): "
             "give --music-guidance 0, so the engine runs it on the music mean as it was trained")
  if args.music_dropout_features and args.music_dropout == 0:
    ap.error("--music-dropout-features chooses the columns --music-dropout replaces: give --music-dropout P > 0 too")
  if not 0.0 <= args.own_inputs <= 1.0:
    ap.error(f"--own-inputs must be in [0, 1], got {args.own_inputs}")
  if args.own_passes < 1:
    ap.error(f"--own-passes must be at least 1, got {args.own_passes}")
  if args.own_passes > 1 and args.own_inputs == 0:
    ap.error("--own-passes repeats --own-inputs' replacement: give --own-inputs P > 0 too")
  if not 0.0 < args.self_share < 1.0:
    ap.error(f"--self-share must be in (0, 1), got {args.self_share}")
  if args.self_tokens and not pathlib.Path(args.self_tokens).is_file():
    ap.error(f"--self-tokens: no file {args.self_tokens}")
  if args.self_tokens and args.carry_state:
    ap.error("--self-tokens is not supported with --carry-state (whole-song lanes)")
  if not 0.0 <= args.style_balance <= 1.0:
    ap.error(f"--style-balance must be in [0, 1], got {args.style_balance}")
  torch.set_num_threads(args.threads)
  os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
  run = pathlib.Path(args.run)
  run.mkdir(parents=True, exist_ok=True)
  log = Logger(run / "train.log")
  stages = args.stages.split(",")
  log(f"start: stages {stages}, args {vars(args)}")
  t0 = time.time()
  if "data" in stages:
    td.ensure_motion_cache()
  if "vq" in stages and not (run / "vq_report.json").is_file():
    stage_vq(args, run, log)
  if "vqdec" in stages and args.vq_dec_iters > 0 and not args.vq_run and not args.vq_model and \
      not (run / "vqdec_report.json").is_file():
    stage_vqdec(args, run, log)
  vq_run = pathlib.Path(args.vq_run) if args.vq_run else run
  if any(s in stages for s in ("seq", "eval", "export")):
    from training import train_seq
    if args.vq_model:
      from training.export import load_models
      vqs = load_models(args.vq_model)[1]
    else:
      vqs = load_vqs(vq_run)
    cfg = SeqConfig(d_model=args.d_model, n_head=args.n_head, codebook_size=vqs["upper"].cfg.codebook_size,
                    music_lookahead_steps=args.lookahead, use_pre=not args.no_pre,
                    use_gate=not args.no_gate, shared_mamba=args.shared_mamba,
                    n_styles=len(td.run_styles(td.load_split())))
    factors = tuple(float(f) for f in args.tempo_factors.split(","))
    if "seq" in stages and args.tempo_ref > 0 and not args.init_model and args.pretrain_iters > 0:
      # From scratch on the warped timeline alone the model memorises the 31 training songs (measured:
      # validation loss 3.03 at 300 iterations, 3.28 at 500, while the training loss fell to 0.86); the
      # tempo-augmented real-time pairs (5x the data) teach the motion first, the warped phase then learns
      # the dance in beat time (docs/training.md).
      args.init_model = str(pretrain_seq(args, cfg, vqs, factors, run, vq_run, log))
      args.lr = args.finetune_lr
    if "seq" in stages:
      train_seq.stage_seq(args, cfg, vqs, factors, run, log)
    base_vqs, vqs = vqs, own_decoder(vqs, run, args)  # the owndec stage's decoders if they fit seq.pt and settings
    # Fixed-rate models are evaluated from the checkpoint (torch generator) and the report goes into the
    # export; tempo-normalised ones are evaluated from the exported file by the engine.
    if "eval" in stages and args.tempo_ref <= 0:
      train_seq.stage_eval(args, vqs, run, log)
    if "export" in stages:
      train_seq.stage_export(args, vqs, run, log)
    if "owndec" in stages and "export" not in stages:
      log("owndec: skipped (it dances the model the export stage writes: run it with --stages export,owndec)")
    fit_own = args.own_iters > 0 and own_parts(args) and args.tempo_ref > 0
    if "owndec" in stages and fit_own and "export" in stages:
      if owndec_current(run, args) is None:
        vqs = stage_owndec(args, base_vqs, run, log)
        train_seq.stage_export(args, vqs, run, log)
    if "eval" in stages and args.tempo_ref > 0:
      train_seq.stage_eval(args, vqs, run, log)
  from training.train_plots import plot_run
  plot_run(run, run)
  log(f"done in {(time.time() - t0) / 60:.1f} min; curves {run}/training_vq.png, {run}/training_seq.png")
  return 0


if __name__ == "__main__":
  raise SystemExit(main())
