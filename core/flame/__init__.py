"""FLAME-format head models: safe file loading, linear blend skinning, the procedural default head."""
