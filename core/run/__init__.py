"""A training run's folder: its file names (:mod:`.names`) and the one reader (:mod:`.folder`)."""
