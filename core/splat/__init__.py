"""The differentiable CPU Gaussian splat engine."""
