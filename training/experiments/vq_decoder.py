"""Decoder-only fine-tuning of a model file's pose VQ-VAEs, outside a training run (how `default-20261204-5`'s
upper decoder was made; the one command's vqdec and owndec stages do the same inside a run).

    OMP_WAIT_POLICY=PASSIVE .venv/bin/python -m training.experiments.vq_decoder --model models/default.dncw \
        --iters 1500 --energy-weight 1 --out /tmp/vqdec/e1 [--export OUT.dncw]
        [--own-dances DIR --own-weight W --own-anchor A]      # and the own-codes term on the engine's dances
    .venv/bin/python -m training.experiments.vq_recon --upper-ckpt /tmp/vqdec/e1/vq_upper.pt \
        --lower-ckpt /tmp/vqdec/e1/vq_lower.pt

The losses are training.common.decoder_tuning's (its docstring). Writes <out>/vq_upper.pt and
<out>/vq_lower.pt in the vq stage's checkpoint format ("model", "cfg", "history", "iter"), which
training.experiments.vq_recon --upper-ckpt / --lower-ckpt read. With --export FILE it also writes the model
file with the fine-tuned decoders: every other tensor and the metadata as in --model (the fine-tuning
recorded under training.vqdec), f16 like the shipped file.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

import torch

from training.common.decoder_tuning import finetune_decoder, training_arrays
from training.export import export_model, load_models
from training.model.vqvae import PoseVQVAE


def main(argv=None) -> int:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--model", default="models/default.dncw", help="the .dncw file whose VQ-VAEs to fine-tune")
  ap.add_argument("--iters", type=int, default=1500, help="iterations per part")
  ap.add_argument("--energy-weight", type=float, default=1.0)
  ap.add_argument("--lr", type=float, default=1e-4)
  ap.add_argument("--batch", type=int, default=32)
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--parts", default="upper,lower")
  ap.add_argument("--mirror", action="store_true", help="also the mirrored training motion (as --vq-mirror)")
  ap.add_argument("--threads", type=int, default=1)
  ap.add_argument("--own-dances", default=None,
                  help="directory of the engine's dances on the training songs (OwnCodes; with --own-weight)")
  ap.add_argument("--own-weight", type=float, default=0.0)
  ap.add_argument("--own-steps", type=int, default=32, help="model steps per own-codes window (4 frames each)")
  ap.add_argument("--own-anchor", type=float, default=0.0,
                  help="weight of the posture anchor inside the own-codes term (window mean pose as decoded before)")
  ap.add_argument("--out", required=True, help="directory for vq_upper.pt / vq_lower.pt")
  ap.add_argument("--export", default=None, help="also write the model file with the fine-tuned decoders here")
  ap.add_argument("--model-id", default=None, help="--export: the new file's model id (default: --model's)")
  args = ap.parse_args(argv)
  torch.set_num_threads(args.threads)
  seq, vqs, meta = load_models(args.model)
  out = pathlib.Path(args.out)
  out.mkdir(parents=True, exist_ok=True)
  for part in args.parts.split(","):
    t0 = time.time()
    vq = vqs[part]
    hist = finetune_decoder(vq, part, training_arrays(part, args.mirror), args.iters, args.energy_weight,
                            lr=args.lr, batch=args.batch, seed=args.seed, own_dances=args.own_dances,
                            own_weight=args.own_weight, own_anchor=args.own_anchor,
                            own_steps=args.own_steps)
    torch.save({"model": vq.state_dict(), "cfg": vq.cfg.to_dict(), "history": hist, "iter": args.iters,
                "finetune": {k: v for k, v in vars(args).items()}}, out / f"vq_{part}.pt")
    print(f"vqdec-{part}: {args.iters} iterations in {time.time() - t0:.0f} s -> {out / f'vq_{part}.pt'}",
          flush=True)
  (out / "args.json").write_text(json.dumps(vars(args), indent=1))
  if args.export:
    export_with_decoders(args.export, seq, vqs, meta, vars(args), args.model_id)
    print(f"vqdec: wrote {args.export}", flush=True)
  return 0


def export_with_decoders(path: str, seq, vqs: dict[str, PoseVQVAE], meta: dict, finetune: dict,
                         model_id: str | None = None) -> None:
  """Writes `path`: the sequence model and VQ-VAEs given (decoders fine-tuned), metadata `meta` with the
  fine-tuning under training.vqdec and the model id replaced if given; big matrices f16 (export.f16_policy).
  Atomic: a failed write leaves an existing file (even the source model) intact."""
  extra = json.loads(json.dumps(meta))
  if model_id:
    extra["model_id"] = model_id
  extra.setdefault("training", {})["vqdec"] = {k: v for k, v in finetune.items() if k not in ("export", "model_id")}
  tmp = f"{path}.tmp.dncw"
  export_model(tmp, seq, vqs, extra, weights_dtype="f16")
  os.replace(tmp, path)


if __name__ == "__main__":
  raise SystemExit(main())
