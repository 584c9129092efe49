"""MoGaFace's modules: expression correction, the momentum expression bank, latent texture attention."""
