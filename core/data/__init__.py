"""Capture datasets (GaussianAvatars/VHAP layout) and the synthetic capture generator."""
