"""SGMD, the motion-diffusion editor beside the token model (docs/diffusion.md): its motion vector, data,
training command, sampler and export."""
