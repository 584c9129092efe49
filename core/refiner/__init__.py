"""The multi-view refiner: per-frame FLAME parameters read from images by comparing them with the
avatar's own render, trained on fresh known offsets so it cannot memorise frames.

- :mod:`.groups`: which parameters it regresses and each group's expected error (its scale);
- :mod:`.sampler`: the random offsets of training, new every step;
- :mod:`.crops`: the head crop of a view (a crop camera for renders, the same window of an image);
- :mod:`.network`: encoder per view, camera token, attention over views, zero-initialised head;
- :mod:`.inference`: K passes, re-rendering between them;
- :mod:`.training`: training on a finished run with the avatar frozen;
- :mod:`.files`: ``RUN/refiner.pt``, written atomically, read ``weights_only``.
"""
