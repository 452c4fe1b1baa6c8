"""The export stage: <run>/seq.pt and the run's VQ-VAEs written as one .dncw file (config.out; training.export,
docs/weights-format.md) with the run's metadata: model id, feature layout, skeleton, styles, time base and
sampling defaults (training.common.run_meta), and the training reports (vq, vqdec, eval, and owndec when it
fits this sequence model). A file written into models/ also gets its golden fixtures (tests/golden/<stem>).
"""
from __future__ import annotations

import json
import pathlib
import time

from training.common import clips as td
from training.common import run_meta
from training.common.run_dir import load_seq, owndec_current
from training.export import export_model
from training.fixtures import FEATURES_META, skeleton_meta, write_fixtures
from training.run_config import RunConfig


def run(config: RunConfig, vqs: dict, log) -> None:
  run_dir = config.run
  model = load_seq(run_dir)
  out = pathlib.Path(config.out)
  model_id = config.model_id or out.stem + "-" + time.strftime("%Y%m%d")
  extra = {"model_id": model_id, "features": FEATURES_META,
           "skeleton": skeleton_meta(), "styles": td.ALL_STYLES[:model.cfg.n_styles],
           "training": {"run": str(run_dir)}, "time_base": run_meta.time_base_meta(config, run_dir, log)}
  extra["sampling"] = run_meta.sampling_meta(config)
  for name in ("vq_report.json", "vqdec_report.json", "eval_report.json"):
    if (run_dir / name).is_file():
      extra["training"][name.removesuffix(".json")] = json.loads((run_dir / name).read_text())
  own = owndec_current(run_dir, config)  # only when fitted to this sequence model with these settings
  if own is not None:
    extra["training"]["owndec_report"] = own
  export_model(str(out), model, vqs, extra, weights_dtype=config.weights_dtype)
  log(f"export: {out} ({out.stat().st_size / 1e6:.1f} MB)")
  if out.parent.resolve() == (td.REPO / "models").resolve():
    idx = write_fixtures(out.resolve(), td.REPO / "tests" / "golden" / out.stem)
    log(f"fixtures: tests/golden/{out.stem} ({len(idx['arrays'])} arrays)")
