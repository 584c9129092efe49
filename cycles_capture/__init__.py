"""Cycles ground truth for synthetic captures: the child process ``python -m mogaface.cycles_capture JOB``
that builds the head's scene with bpy and renders the images a job lists (see
:mod:`mogaface.core.data.cycles_job`, which writes the job and starts it)."""
