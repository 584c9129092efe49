"""The multi-view refiner: per-frame FLAME parameters read from images by comparing them with the
avatar's own render, learnt from fresh known offsets so it cannot memorise frames.

- :mod:`.groups`: which parameters it regresses and each group's expected error (its scale);
- :mod:`.sampler`: the random offsets of training, new for every observation;
- :mod:`.crops`: the head window of a view (a crop camera for renders, the same window of an image);
- :mod:`.views`: the crops at the window's own pixel size and their pooled difference;
- :mod:`.model`: per camera a linear forward model and a noise model; a pass is one least-squares solve;
- :mod:`.inference`: K passes; of two or more, each kept only when the views agree it helps;
- :mod:`.training`: the forward models from renders and the capture gap, the avatar frozen;
- :mod:`.files`: ``RUN/refiner.pt``, written atomically, read ``weights_only``.
"""
