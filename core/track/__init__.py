"""Tracking footage: a phone's video or photos become a capture folder, on the CPU, offline.

The room between the footage and the capture (below the users of :mod:`..data`, above
:mod:`..flame`): reading frames (``decode``), finding the face, its landmarks and the person's mask
(``detect``, on MediaPipe's models: ``models``, ``mediapipe_face``, ``mediapipe_ibug68``), fitting
the head model (``fit``). Importing this package imports nothing heavy.
"""
