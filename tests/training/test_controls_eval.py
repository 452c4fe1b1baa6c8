"""training.eval.controls_eval end to end on one song through the engine: the conditions it writes from a
dance are read by dance-generate, and its constraint errors see the given motion kept exactly (the C++
side is tested in tests/engine/runtime/controls_test.cc)."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from training import tools
from training.eval import controls_eval, evaluate

REPO = pathlib.Path(__file__).resolve().parents[2]
SONG = REPO.parent / "shared" / "data" / "tang2018" / "DANCE_W_3" / "audio.ogg"


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> evaluate.Dance:
  """The engine's own waltz on a real song, standing in for a real dance (starting 2.5 s into the song)."""
  try:
    tools.require("dance-generate")
  except tools.ToolMissing as e:
    pytest.skip(str(e))
  if not SONG.exists():
    pytest.skip(f"no song at {SONG}")
  out = tmp_path_factory.mktemp("ref") / "ref.json"
  tools.dance_generate(REPO / "models" / "default.dncw", SONG, out, seed=5, style="waltz")
  d = evaluate.load_dance(out, audio=str(SONG))
  a = int(round((2.5 - d.audio_offset_s) * 30))
  return evaluate.Dance("ref", d.positions[a:a + 900], 30.0, str(SONG), d.audio_offset_s + a / 30, "waltz")


@pytest.mark.parametrize("task", ["seed", "inpaint", "upper_generated", "lower_generated", "inbetween",
                                  "trajectory"])
def test_controls_keep_what_is_given(reference, tmp_path, task):
  conditions = controls_eval.write_conditions(reference, tmp_path / "inputs")
  flags, seams = conditions[task]
  gen, summary = controls_eval.generate(str(REPO / "models" / "default.dncw"), reference, flags,
                                        tmp_path / f"{task}.json", seed=1)
  assert summary["wall_s"] > 0 and summary["steps"] > 0
  cut = evaluate.on_real_spans([gen], [reference])[0]
  assert len(cut.positions) == len(reference.positions)
  errors = controls_eval.constraint_errors(task, cut, reference, seams)
  if task == "trajectory":
    assert errors["traj_mean_cm"] < 30.0, errors  # measured ~10 cm (docs/controls.md)
  elif task == "inbetween":
    assert errors["key_err_cm"] < 0.01, errors
  else:
    assert errors["given_err_cm"] < 0.01, errors
  if seams:
    assert np.isfinite(errors["seam_jump_max"]) and errors["seam_jump_max"] > 0


def test_bad_task_name_is_refused(tmp_path):
  with pytest.raises(SystemExit, match="unknown task 'dancing'"):
    controls_eval.main(["--out-dir", str(tmp_path), "--tasks", "dancing"])
