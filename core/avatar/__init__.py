"""Gaussian head avatars: Gaussians bound to the triangles of a FLAME-format mesh."""
