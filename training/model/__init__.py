"""Torch modules of the streaming Danceba model and the pose VQ-VAEs (docs/model.md)."""
from training.model.config import SeqConfig, VQConfig
from training.model.danceba import Danceba, one_hot_style
from training.model.vqvae import DecoderStream, PoseVQVAE
