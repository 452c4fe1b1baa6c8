"""The seq stage: the sequence model (training.model.danceba) trained on the VQ-VAEs' codes of the paired
dances, with past-motion dropout (training.common.tokens) and, as configured, music dropout, own-code inputs
(training.common.seq_inputs), whole-song lanes (training.common.lanes), multi-step heads and a weight average.

A tempo-normalised run from scratch (--tempo-ref > 0, no --init-model, --pretrain-iters > 0: needs_pretrain)
has two phases: training.train first runs this stage and the export with pretrain_config, the fixed-rate model
on the tempo-augmented real-time pairs in <run>/pretrain (its own seq.pt and an f32 model.dncw), then with
after_pretrain, which fine-tunes that model on the engine's tempo-normalised timeline at --finetune-lr. From scratch on the warped timeline alone the model memorises the 31 training songs
(measured: validation loss 3.03 at 300 iterations, 3.28 at 500, while the training loss fell to 0.86); the
tempo-augmented pairs (5x the data) teach the motion first (docs/research-log.md).

Writes <run>/seq.pt (model, optimizer, history, the batch sampler's and torch's random states: a resumed run
trains exactly as an uninterrupted one), seq_history.json (the curves) and the token caches
tokens_{train,val}_<tag>.pt beside the VQ-VAEs (config.vq_dir).
"""
from __future__ import annotations

import dataclasses
import json
import math
import time

import numpy as np
import torch
from tqdm import tqdm

from training.common import clips as td
from training.common import run_meta
from training.common.lanes import Lanes, detach, reset_rows
from training.common.run_dir import load_seq
from training.common.seq_inputs import as_the_engine_reads, drop_music, own_code_inputs
from training.common.seq_loss import AuxHeads, code_loss, validation
from training.common.tokens import STEPS, STYLE_DROPOUT, build_tokens, make_batch
from training.export import load_models
from training.model.config import SeqConfig
from training.model.danceba import Danceba
from training.model.layers import set_residual_dropout
from training.run_config import RunConfig


def seq_config(config: RunConfig, vqs: dict) -> SeqConfig:
  """The sequence model's architecture for a run from scratch (an --init-model run takes its parent's)."""
  return SeqConfig(d_model=config.d_model, n_head=config.n_head, codebook_size=vqs["upper"].cfg.codebook_size,
                   music_lookahead_steps=config.lookahead, use_pre=not config.no_pre,
                   use_gate=not config.no_gate, shared_mamba=config.shared_mamba,
                   n_styles=len(td.run_styles(td.load_split())))


def needs_pretrain(config: RunConfig) -> bool:
  """A tempo-normalised run from scratch starts with the fixed-rate phase (module docstring)."""
  return config.tempo_ref > 0 and not config.init_model and config.pretrain_iters > 0


def pretrain_config(config: RunConfig) -> RunConfig:
  """The fixed-rate phase of `config`: its own run directory <run>/pretrain, the same VQ-VAEs and token
  caches, an f32 model file <run>/pretrain/model.dncw (training.train runs this stage and the export on it)."""
  sub = config.run / "pretrain"
  return dataclasses.replace(
      config, run=sub, out=sub / "model.dncw", vq_run=config.vq_dir, tempo_ref=0.0,
      seq_iters=config.pretrain_iters, init_model=None, weights_dtype="f32",
      model_id="pretrain",  # an intermediate file: never the id given for the final export
      # own-code inputs, the weight average and the carried state: the tempo-normalised phase only (the
      # multi-step heads, --aux-steps, train in both phases)
      own_inputs=0.0, ema=0.0, carry_state=False,
      self_tokens=None)  # the model's own draws are on the warped timeline


def after_pretrain(config: RunConfig, phase: RunConfig) -> RunConfig:
  """The tempo-normalised phase: the fixed-rate phase's model file fine-tuned at --finetune-lr."""
  return dataclasses.replace(config, init_model=phase.out, lr=config.finetune_lr)


def _tokens(config: RunConfig, vqs: dict, log) -> tuple[list[dict], list[dict]]:
  """The training and validation tokens of the run's timeline (cached beside the VQ-VAEs), with the
  --warp-tempo-styles filter and the --self-tokens clips."""
  run = config.run
  split = td.load_split()
  train_ids = td.paired_ids(split["train"])
  val_ids = td.paired_ids(split["validation"])
  vq_dir = config.vq_dir
  factors = config.tempo_factors
  refs = run_meta.style_refs_of(config, run, log)
  bars = run_meta.bar_clock_of(config)
  warp_factors = tuple(config.warp_tempo_factors)
  fold = run_meta.fold_tempo_of(config)
  tag = run_meta.warp_tag(refs, bars, fold) if refs else "_".join(f"{f:g}" for f in factors)
  train_tag = tag + ("_x" + "_".join(f"{f:g}" for f in warp_factors) if refs and warp_factors != (1.0,) else "")
  vq_dir.mkdir(parents=True, exist_ok=True)
  mirror = config.mirror
  train_toks = build_tokens(train_ids, factors, vqs, log,
                            vq_dir / f"tokens_train_{train_tag}{'_mirror' if mirror else ''}.pt", refs, bars, mirror,
                            warp_factors if refs else (1.0,), fold)
  warp_styles = ",".join(config.warp_tempo_styles)
  if refs and warp_styles:  # the other styles keep only their songs at their own tempo
    keep = {td.style_index(st) for st in config.warp_tempo_styles}
    train_toks = [t for t in train_toks if t["factor"] == 1.0 or t["style"] in keep]
    log(f"seq: tempo factors {warp_factors} for {warp_styles} only: {len(train_toks)} clips")
  val_toks = build_tokens(val_ids, (1.0,), vqs, log, vq_dir / f"tokens_val_{tag}.pt", refs, bars, fold_tempo=fold)
  if config.self_tokens:  # filtered self-training (training.experiments.self_rollouts): the model's own kept draws
    extra = torch.load(config.self_tokens)
    if extra and len(extra[0]["music"][0]) != len(train_toks[0]["music"][0]):
      raise SystemExit(f"seq: {config.self_tokens} has music features of another width than this run's tokens")
    train_toks = train_toks + [dict(t, own_draw=True) for t in extra]  # (files written before the mark too)
    log(f"seq: {len(extra)} clips of the model's own kept draws from {config.self_tokens} "
        f"({sum(len(t['upper']) for t in extra)} steps), share of the windows {config.self_share}")
  return train_toks, val_toks


def _model(config: RunConfig, cfg: SeqConfig, train_toks: list[dict], log) -> Danceba:
  """A fresh model with the training music's normalisation, or the --init-model file's sequence model."""
  if not config.init_model:
    model = Danceba(cfg)
    base = [t for t in train_toks if t["factor"] == 1.0]
    allm = np.concatenate([t["music"] for t in base])
    with torch.no_grad():
      model.music_mean.copy_(torch.from_numpy(allm.mean(0)))
      model.music_std.copy_(torch.from_numpy(np.maximum(allm.std(0), 1e-2)))
    return model
  # Fine-tune an exported model (its music normalisation and its PRE BatchNorm, folded, stay as they are).
  parent = load_models(str(config.init_model))[0]
  # Ablation flags (and the music shift) override the parent's architecture; every parameter whose name
  # and shape still match is copied, the rest starts fresh (fine-tuned ablations from one parent).
  want = dataclasses.replace(parent.cfg, use_pre=parent.cfg.use_pre and not config.no_pre,
                             use_gate=parent.cfg.use_gate and not config.no_gate,
                             shared_mamba=parent.cfg.shared_mamba or config.shared_mamba,
                             music_lookahead_steps=config.lookahead or parent.cfg.music_lookahead_steps)
  if want == parent.cfg:
    model = parent
  else:
    model = Danceba(want)
    mine = model.state_dict()
    theirs = parent.state_dict()
    copied = {k: v for k, v in theirs.items() if k in mine and mine[k].shape == v.shape}
    model.load_state_dict(copied, strict=False)
    log(f"seq: architecture changed from the parent ({len(copied)}/{len(mine)} tensors copied)")
  log(f"seq: initialised from {config.init_model}")
  return model


@torch.no_grad()
def update_ema(ema: dict, model, decay: float) -> None:
  """ema <- decay ema + (1 - decay) weights, for every floating-point tensor (buffers copied)."""
  for k, v in model.state_dict().items():
    if v.dtype.is_floating_point:
      ema[k].mul_(decay).add_(v, alpha=1.0 - decay)
    else:
      ema[k].copy_(v)


def run(config: RunConfig, cfg: SeqConfig, vqs: dict, log) -> None:
  """Trains (or resumes) <run>/seq.pt for config.seq_iters iterations; cfg: the architecture of a model from
  scratch (seq_config)."""
  run_dir = config.run
  ck_path = run_dir / "seq.pt"
  train_toks, val_toks = _tokens(config, vqs, log)
  torch.manual_seed(0)
  rng = np.random.default_rng(0)
  model = _model(config, cfg, train_toks, log)
  cfg = model.cfg
  n_params = sum(p.numel() for p in model.parameters())
  log(f"seq: {n_params} parameters, cfg {json.dumps(cfg.to_dict())}")
  if config.dropout > 0:
    n_drop = set_residual_dropout(model, config.dropout)
    log(f"seq: residual dropout {config.dropout:g} on {n_drop} residual branches (training only)")
  aux_steps, aux_weight = config.aux_steps, config.aux_weight
  aux = AuxHeads(cfg.d_model, cfg.codebook_size, aux_steps) if aux_steps > 1 and aux_weight > 0 else None
  if aux is not None:
    log(f"seq: multi-step prediction, codes 2..{aux_steps} steps ahead at weight {aux_weight:g} (training only)")
  opt = torch.optim.AdamW(list(model.parameters()) + (list(aux.parameters()) if aux is not None else []),
                          lr=config.lr, weight_decay=0.05)
  lr0 = opt.param_groups[0]["lr"]
  history, start, elapsed = [], 0, 0.0
  ema_decay = config.ema
  ema = {k: v.detach().clone() for k, v in model.state_dict().items()} if ema_decay > 0 else None
  if ck_path.is_file():
    ck = torch.load(ck_path)
    model.load_state_dict(ck["model"])
    if ema is not None and ck.get("ema") is not None:
      ema = ck["ema"]
    if (aux is None) != (ck.get("aux") is None):
      raise SystemExit(f"seq: {ck_path} was trained {'without' if aux is not None else 'with'} --aux-steps "
                       "(its optimizer state does not fit): resume with the same option or use another --run")
    if aux is not None:
      aux.load_state_dict(ck["aux"])
    opt.load_state_dict(ck["opt"])
    history, start, elapsed = ck["history"], ck["iter"], ck.get("elapsed", 0.0)
    if "rng" in ck:  # the batch sampler and torch continue where they stopped: a resume changes nothing
      rng.bit_generator.state = ck["rng"]
      torch.set_rng_state(ck["torch_rng"])
    else:  # a checkpoint from before the random states were saved
      rng = np.random.default_rng(start)
  iters = config.seq_iters

  def train_mode():
    model.train()
    if config.init_model and cfg.use_pre:
      model.pre.bn.eval()  # keep the folded statistics (identity) of the exported model

  own, own_passes = config.own_inputs, config.own_passes
  music_dropout, music_ranges = config.music_dropout, config.music_dropout_features
  if music_dropout > 0:
    log(f"seq: music dropout {music_dropout:g} (a window's music replaced by the mean, PRE kept"
        + (f"; feature columns {list(music_ranges)} only)" if music_ranges else ")"))
  engine_val = as_the_engine_reads(config, model, val_toks)
  if engine_val is not val_toks:
    val_toks = engine_val
    log("seq: validation reads the music mean, as the engine does at music guidance 0")
  balance = config.style_balance
  self_share = config.self_share if config.self_tokens else None
  lanes = Lanes(train_toks, cfg, rng, config.batch, STEPS, balance) if config.carry_state else None
  carried = None
  if lanes is not None and ck_path.is_file() and ck.get("lanes") is not None:
    lanes.restore(ck["lanes"])
    carried = ck.get("carried")
  train_mode()
  t_start = time.time() - elapsed

  def save(it):
    torch.save({"model": model.state_dict(), "ema": ema, "opt": opt.state_dict(), "history": history,
                "iter": it, "cfg": cfg.to_dict(), "elapsed": time.time() - t_start, "rng": rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(),
                "lanes": lanes.snapshot() if lanes is not None else None, "carried": carried,
                "aux": aux.state_dict() if aux is not None else None}, ck_path)

  for it in tqdm(range(start, iters), desc="seq", initial=start, total=iters, mininterval=10):
    warm = min(1.0, (it + 1) / 200)
    for g in opt.param_groups:
      g["lr"] = lr0 * warm * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * it / iters)))
    if lanes is not None:
      inputs, targets, fresh = lanes.next(code_mask=config.code_mask, style_dropout=STYLE_DROPOUT)
      carried = reset_rows(detach(carried), fresh)
    else:
      inputs, targets = make_batch(train_toks, cfg, rng, batch=config.batch, code_mask=config.code_mask,
                                   style_dropout=STYLE_DROPOUT, style_balance=balance, self_share=self_share)
    if music_dropout > 0:  # (only then: a run without it draws exactly the batches it drew before)
      inputs = drop_music(model, inputs, music_dropout, rng, music_ranges)
    if own > 0:
      inputs = own_code_inputs(model, inputs, own, state=carried, passes=own_passes)
    trace = {} if aux is not None else None
    lu, ll, after = model.forward_with_state(*inputs, carried, trace)
    if lanes is not None:
      carried = detach(after)
    loss = code_loss(lu, ll, targets)
    total = loss + aux_weight * aux.loss(trace["norm_f"], targets) if aux is not None else loss
    opt.zero_grad()
    total.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
    opt.step()
    if ema is not None:
      update_ema(ema, model, ema_decay)
    if it % 25 == 0:
      history.append({"iter": it, "loss": float(loss)})
    if it % config.val_every == config.val_every - 1 or it == iters - 1:
      v = validation(model, val_toks, cfg)
      train_mode()
      history.append(dict(v, iter=it + 1, minutes=(time.time() - t_start) / 60))
      log(f"seq iter {it + 1}/{iters} train {float(loss):.3f} {json.dumps(v)}")
      save(it + 1)
      (run_dir / "seq_history.json").write_text(json.dumps(history))
      if config.seq_minutes and (time.time() - t_start) / 60 > config.seq_minutes:
        log(f"seq: time budget of {config.seq_minutes} min reached at iter {it + 1}")
        break
  save(it + 1 if iters > start else start)
  (run_dir / "seq_history.json").write_text(json.dumps(history))
  if ema is not None:
    averaged = load_seq(run_dir)
    v = validation(averaged, val_toks, cfg)
    log(f"seq: weight average (decay {ema_decay:g}, exported): {json.dumps(v)}")
  log(f"seq: {(time.time() - t_start) / 60:.1f} min")
