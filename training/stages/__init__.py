"""The stages of a training run, in the order training.train runs them; each module has a `run` function
that takes the RunConfig (training.run_config) and reads and writes the run directory (config.run):

    data    the motion cache (training.data.prepare) when it is missing
    vq      the pose VQ-VAEs, upper and lower body                      vq_{part}.pt, vq_report.json
    vqdec   their decoders fine-tuned with the energy term               vqdec_{part}.pt, vqdec_report.json
    seq     the sequence model: the fixed-rate phase (pretrain/), then the tempo-normalised one   seq.pt
    export  the model file (config.out; in models/: also its golden fixtures)
    owndec  the decoders fitted to the model's own codes, then export again    owndec_{part}.pt
    eval    losses, tempo following and the metric table               eval_report.json

A stage whose output exists is skipped (vq, vqdec, owndec) or resumed from its checkpoint (vq, seq), so a
stopped run continues where it stopped. The stages share the helpers in training/common; they do not import
each other.
"""
