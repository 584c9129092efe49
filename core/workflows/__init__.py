"""Workflows that combine training, scoring and the refiner: they sit above the parts they combine,
so no model package imports back up.

- :mod:`.ablation`, :mod:`.ablation_table`: the ablation ladder (``ablate``): train, score, tabulate;
- :mod:`.refine_tracking`: a capture's tracking improved by a run's refiner (``refine-tracking``,
  Blender's Improve Tracking), training the refiner first where the run has none.
"""
