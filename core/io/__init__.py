"""File formats: atomic writes, images (PNG/EXR), meshes and Gaussian PLY files."""
