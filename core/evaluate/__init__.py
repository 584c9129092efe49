"""Evaluation: the protocols, the parameter sources and what they score (image metrics are in
:mod:`mogaface.core.metrics`)."""
